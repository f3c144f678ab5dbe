"""The fit stage's table: what ``prt train`` fits besides the visibility models, one hook per method package.

``prt train`` (:func:`prt_torch.fit.train.train_dataset`) fits the visibility kinds, then runs every
:class:`FitHook` of :data:`FIT_STAGES` in the table's order. A hook owns one optional section of the train config
(``train.transfer``, ``train.local``, ``train.s001``: a :class:`~prt_torch.fit.config.TrainConfig` field that is
``None`` when unset), its files in the run directory and one key of ``metrics.json``. Its :attr:`FitHook.run` is
called whether the section is set or not: unset, it removes the files a previous training left (they no longer
belong to this training) and returns ``None``.

The stage key (:func:`prt_torch.fit.train.train_key`) leaves a hook's section out while it is unset, so the keys
of runs trained before the section existed stay valid.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from prt_torch.plugins import StageTable, hooks

#: the fit hooks of each method package (:class:`FitHook` references); they run in this table's order (transfer,
#: local, s001: the order of their console lines)
FIT_STAGES: StageTable = {
    "transfer": ("prt_torch.transfer.fit:FIT_HOOK",),
    "local": ("prt_torch.local.fit:FIT_HOOK",),
    "s001": ("prt_torch.s001.fit:FIT_HOOK",),
    "shexp": (),
    "vct": (),
    "heightfield": (),
    "cloth": (),
}


@dataclass(frozen=True)
class FitHook:
    """One method's part of ``prt train``.

    Attributes:
        section: its :class:`~prt_torch.fit.config.TrainConfig` field (config ``train.<section>``; ``None``: unset).
        metrics_key: its key in ``metrics.json``.
        run: ``run(ds, run, cfg, splits, progress) -> metrics part | None``: ``ds`` the
            :class:`~prt_torch.bake.store.BakedDataset`, ``run`` the :class:`~prt_torch.rundir.RunDir`, ``cfg`` the
            :class:`~prt_torch.fit.config.TrainConfig`, ``splits`` ``{"train": SplitData, "heldout": SplitData}``
            (``heldout`` when baked; read with :attr:`extra`), ``progress`` the progress bar or ``None``. Returns
            its ``metrics.json`` part, ``None`` when the section is unset (its stale files removed).
        check: ``check(ds, cfg)``, called when the section is set, before anything is fitted or written: a
            one-line :class:`~prt_torch.errors.PrtError` when the dataset cannot serve it (``None``: no check).
        extra: the per-frame arrays its ``run`` reads from ``splits`` (``SplitData.extra``) when the section is set.
    """

    section: str
    metrics_key: str
    run: Callable[[Any, Any, Any, dict[str, Any], Any], dict[str, Any] | None]
    check: Callable[[Any, Any], None] | None = None
    extra: tuple[str, ...] = ()

    def is_set(self, cfg: Any) -> bool:
        """Whether ``cfg`` (a :class:`~prt_torch.fit.config.TrainConfig`) sets this hook's section."""
        return getattr(cfg, self.section) is not None


def fit_hooks() -> list[FitHook]:
    """Every :class:`FitHook` of :data:`FIT_STAGES`, loaded, in the table's order (the order they run in)."""
    return hooks(FIT_STAGES)
