"""The sequence sources of ``prt compare``: where a deformable run's clips come from, one hook per method package.

A skinned run's clip (``prt compare --clip``) is posed from the character's motion; a deformable run's frames
come from the method that owns its subject (cloth: the vertex cache of its simulation). Each :class:`SequenceSource`
of :data:`SEQUENCES` reads one named sequence; :func:`sequence_source` picks the one the run config selects.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from prt_torch.errors import PrtError
from prt_torch.plugins import StageTable, hooks

#: the sequence sources of each method package (:class:`SequenceSource` references)
SEQUENCES: StageTable = {
    "s001": (),
    "transfer": (),
    "local": (),
    "shexp": (),
    "vct": (),
    "heightfield": (),
    "cloth": ("prt_torch.cloth.sequences:SEQUENCE_SOURCE",),
}


@dataclass(frozen=True)
class SequenceSource:
    """A deformable subject's named sequences, as ``prt compare`` poses them.

    Attributes:
        section: the run config section that selects this source (``cfg.<section>`` set, e.g. ``"cloth"``).
        read: ``read(cfg, name)``: the sequence ``name`` of the run config ``cfg``, an object with
            ``positions (T, V, 3)`` float32 and ``features (T, A)`` float32 (the dataset's ``pose`` column); a
            missing sequence or cache is a one-line PrtError.
    """

    section: str
    read: Callable[[Any, str], Any]


def sequence_source(cfg: Any) -> SequenceSource:
    """The :class:`SequenceSource` whose section the run config ``cfg`` sets (one-line PrtError when none does)."""
    for src in hooks(SEQUENCES):
        if getattr(cfg, src.section, None) is not None:
            return src
    raise PrtError(f"run {getattr(cfg, 'name', '?')!r}: its config selects no deformable sequence source "
                   f"(none of {[s.section for s in hooks(SEQUENCES)]} is set)")
