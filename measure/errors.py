"""The measurement core's one error type."""


class MeasureError(ValueError):
    """Bad input to the measurement core; the message says what to change.

    A subclass of :class:`ValueError`, raised by the constructors of :class:`PinholeCamera`,
    :class:`Frame` and :class:`MeasureOptions` and by :func:`measure.measure_distance`.

    Args:
        message: what is wrong with the input and what to change (str).

    Returns:
        The exception; it is raised, not returned.

    Examples:
        >>> from measure import MeasureError, MeasureOptions
        >>> try:
        ...     MeasureOptions(window=4)
        ... except MeasureError as err:
        ...     print(err)
        window=4 must be an odd whole number from 1 to 51 (px)
    """
