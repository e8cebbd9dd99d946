"""The batch's error base: every bad table, option, executor or results file is a BatchError whose
message says what to change."""


class BatchError(ValueError):
    """A batch run that cannot go as asked; the message names the file, row or option to change."""
