"""The project's error type.

Every bad input (wrong shape, NaN, unknown file format, missing file, bad config) raises
:class:`PrtError` with a one-line message naming the problem. The ``prt`` CLI prints such errors
as ``error: <message>`` on one line and exits with status 2, without a traceback. A run artifact that cannot be
used raises a subclass saying why: :class:`MissingArtifact`, :class:`StaleArtifact` or :class:`DamagedArtifact`
(all :class:`ArtifactError`), so a caller that falls back catches only the case it means.

An input that is usable but suspect (negative radiance clamped, a config key without effect) is used with a
:class:`PrtWarning` from :func:`warn`, a one-line message saying what was done; the CLI prints it as
``warning: <message>`` on one line (:func:`prt_torch.cli.main`), like any other warning raised while it runs.
"""

from __future__ import annotations

import warnings


class PrtError(ValueError):
    """A user-facing error: bad input, with a one-line message that names the problem."""


class ArtifactError(PrtError):
    """A run directory / store / export file that cannot be used as it is (one of the three below)."""


class MissingArtifact(ArtifactError):
    """A file or store a stage writes is not there (not baked / trained / exported yet)."""


class StaleArtifact(ArtifactError):
    """An artifact made from other inputs than the current ones (re-trained since exported, old format, other
    key): running its stage again makes it current."""


class DamagedArtifact(ArtifactError):
    """An artifact that is there but unreadable or not what its commit record says (bad JSON / npz, sha256
    mismatch, zarr chunk checksum)."""


class PrtWarning(UserWarning):
    """A user-facing warning: a usable input that was used with a change or that has no effect (one line)."""


def check(condition: bool, message: str) -> None:
    """Raise :class:`PrtError` with ``message`` unless ``condition`` holds."""
    if not condition:
        raise PrtError(message)


def warn(message: str) -> None:
    """Warn, with a one-line ``message`` saying what was done, about a usable but suspect input (a
    :class:`PrtWarning` attributed to the caller: Python shows a given message from one place once per process,
    the CLI once per command, as ``warning: <message>``)."""
    warnings.warn(message, PrtWarning, stacklevel=2)
