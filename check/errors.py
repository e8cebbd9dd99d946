"""The check's error: it cannot run as asked, and the message says what to change."""


class CheckError(ValueError):
    """The check cannot run as asked (no board in view, too few corners); the message says what to change."""
