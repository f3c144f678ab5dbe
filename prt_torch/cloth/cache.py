"""The vertex cache ``runs/NAME/simulation.zarr`` (zarr v3): simulated positions of a cloth run's sequences.

Layout (written by :mod:`prt_torch.cloth.simulate`; the store is created complete, every array at its final
shape, in a temporary sibling directory and renamed into place, like :mod:`prt_torch.bake.store`):

* attrs: ``format`` (:data:`FORMAT`), ``config_hash`` (sha256 of what changes the simulated numbers:
  :func:`prt_torch.cloth.simulate.simulation_key`), ``simulation`` (that key itself), ``sequences`` (names in
  store order: train then held-out), ``splits``, ``keys`` (name -> group key ``s000``...), ``frames``
  (name -> T), ``n_vertices`` ``V`` of the WHOLE subject, ``cloth_start``/``cloth_stop`` (the cloth's vertex
  range), ``fps``, ``timestep``, ``library`` versions;
* ``<key>/positions (T, V, 3)`` float32 world positions of the whole subject (cape: skinned body, then cloth);
* ``<key>/body_features (T, A)`` float32 (cape only): the body's pose features of each frame
  (:attr:`prt_torch.rig.character.Poses.features`);
* ``done (S,)`` bool, one chunk per sequence: written after the sequence's arrays (a killed simulation leaves
  the sequence not done, and it is simulated again).
"""

from __future__ import annotations

import os
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from prt_torch.errors import DamagedArtifact, MissingArtifact, PrtError, StaleArtifact

FORMAT = "prt_torch.simulation/1"


class VertexCache:
    """Reader of a vertex cache. ``sequences()`` lists the DONE sequences only; reading an unfinished or unknown
    one is a one-line :class:`PrtError`."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        import zarr

        self.path = Path(path)
        if not self.path.exists():
            raise MissingArtifact(f"vertex cache not found: {self.path} (run `prt simulate CONFIG`)")
        try:
            self._group = zarr.open_group(str(self.path), mode="r")
            attrs = dict(self._group.attrs)
        except Exception as exc:
            raise DamagedArtifact(f"{self.path}: not a vertex cache ({type(exc).__name__})") from None
        if attrs.get("format") != FORMAT:
            raise StaleArtifact(f"{self.path}: not a vertex cache of format {FORMAT!r} (found {attrs.get('format')!r})")
        self.attrs: dict[str, Any] = attrs

    @property
    def config_hash(self) -> str:
        return str(self.attrs["config_hash"])

    @property
    def n_vertices(self) -> int:
        return int(self.attrs["n_vertices"])

    @property
    def cloth_slice(self) -> slice:
        return slice(int(self.attrs["cloth_start"]), int(self.attrs["cloth_stop"]))

    @property
    def fps(self) -> float:
        return float(self.attrs["fps"])

    def all_sequences(self) -> list[str]:
        """Every sequence of the store (done or not), in store order."""
        return list(self.attrs["sequences"])

    @cached_property
    def _done(self) -> np.ndarray:
        return np.asarray(self._group["done"][...], dtype=bool)

    def is_complete(self, name: str | None = None) -> bool:
        """Whether sequence ``name`` (``None``: every sequence) is done."""
        if name is None:
            return bool(self._done.all())
        return bool(self._done[self._index(name)])

    def sequences(self, split: str | None = None) -> list[str]:
        """The done sequences (of ``split``: ``"train"``/``"heldout"``), in store order."""
        names = self.all_sequences()
        if split is not None:
            wanted = set(self.attrs["splits"].get(split, []))
            names = [n for n in names if n in wanted]
        every = self.all_sequences()
        return [n for n in names if self._done[every.index(n)]]

    def _index(self, name: str) -> int:
        names = self.all_sequences()
        if name not in names:
            raise PrtError(f"{self.path}: no sequence {name!r} (has {names})")
        return names.index(name)

    def _array(self, name: str, array: str) -> Any:
        i = self._index(name)
        if not self._done[i]:
            raise PrtError(f"{self.path}: sequence {name!r} is not simulated yet (run `prt simulate CONFIG`)")
        key = self.attrs["keys"][name]
        try:
            return self._group[f"{key}/{array}"]
        except KeyError:
            return None

    def positions(self, name: str) -> np.ndarray:
        """``(T, V, 3)`` float32 positions of the whole subject."""
        a = self._array(name, "positions")
        try:
            return np.asarray(a[...], dtype=np.float32)
        except Exception as exc:
            raise PrtError(f"{self.path}: sequence {name!r}: positions do not decode ({type(exc).__name__}); "
                           "delete the cache and simulate again") from None

    def body_features(self, name: str) -> np.ndarray | None:
        """``(T, A)`` float32 body pose features (cape), ``None`` for a subject without a body."""
        a = self._array(name, "body_features")
        return None if a is None else np.asarray(a[...], dtype=np.float32)

    def __repr__(self) -> str:
        return f"VertexCache({str(self.path)!r}, done={int(self._done.sum())}/{self._done.size})"
