"""The project's error type.

Every bad input (wrong shape, NaN, unknown file format, missing file, bad config) raises
:class:`PrtError` with a one-line message naming the problem. The ``prt`` CLI prints such errors
as ``error: <message>`` on one line and exits with status 2, without a traceback.
"""

from __future__ import annotations


class PrtError(ValueError):
    """A user-facing error: bad input, with a one-line message that names the problem."""


def check(condition: bool, message: str) -> None:
    """Raise :class:`PrtError` with ``message`` unless ``condition`` holds."""
    if not condition:
        raise PrtError(message)
