"""The cloth's hook for ``prt compare --clip`` (:data:`prt_torch.compare.sequences.SEQUENCES`): a cached sequence
of the run's vertex cache, its positions checked and its pose features computed by the bake's rule."""

from __future__ import annotations

from typing import Any

from prt_torch.cloth.bake import CachedSequence, load_subject, open_cache, sequence_frames
from prt_torch.compare.sequences import SequenceSource


def read_sequence(cfg: Any, name: str) -> CachedSequence:
    """The cached sequence ``name`` of the run config ``cfg`` (its subject and vertex cache):
    :func:`prt_torch.cloth.bake.sequence_frames`."""
    return sequence_frames(cfg, load_subject(cfg), open_cache(cfg), name)


#: the cloth's sequences for ``prt compare`` (the ``cloth:`` section selects it)
SEQUENCE_SOURCE = SequenceSource(section="cloth", read=read_sequence)
