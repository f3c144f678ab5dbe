"""Per-frame step timings: collection, summary (frames/s) and JSON output."""

from __future__ import annotations

import os
import time
from collections import defaultdict
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np

from prt_torch.io import atomic_write_json


class FrameTimer:
    """Collects ``{step: [seconds per frame]}``; ``with timer.step("pose"): ...`` times one step."""

    def __init__(self) -> None:
        self.steps: dict[str, list[float]] = defaultdict(list)

    @contextmanager
    def step(self, name: str) -> Iterator[None]:
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.steps[name].append(time.perf_counter() - t0)

    def add(self, name: str, seconds: float) -> None:
        self.steps[name].append(float(seconds))

    def summary(self, compute_steps: tuple[str, ...] = ("pose", "visibility", "shading", "fused", "compiled", "peaks",
                                                   "colors"),
                ) -> dict[str, Any]:
        """Median/mean ms per step, and frames/s of the compute path (``compute_steps``) and of all steps."""
        out: dict[str, Any] = {"steps_ms": {}}
        n = max((len(v) for v in self.steps.values()), default=0)
        for name, v in self.steps.items():
            a = np.asarray(v) * 1e3
            out["steps_ms"][name] = {"median": float(np.median(a)), "mean": float(a.mean()), "min": float(a.min()),
                                     "n": int(a.size)}
        comp = [np.asarray(self.steps[s]) for s in compute_steps if s in self.steps and len(self.steps[s]) == n]
        every = [np.asarray(v) for v in self.steps.values() if len(v) == n]
        if n and comp:
            per = np.sum(comp, axis=0)
            out["compute_ms_median"] = float(np.median(per) * 1e3)
            out["compute_fps"] = float(1.0 / np.median(per))
        if n and every:
            per = np.sum(every, axis=0)
            out["total_ms_median"] = float(np.median(per) * 1e3)
            out["total_fps"] = float(1.0 / np.median(per))
        out["frames"] = n
        return out

    def write_json(self, path: str | os.PathLike[str], extra: dict[str, Any] | None = None) -> None:
        """Write the summary plus every frame's step times (ms) atomically."""
        data = {**(extra or {}), "summary": self.summary(),
                "frames_ms": {k: [round(x * 1e3, 4) for x in v] for k, v in self.steps.items()}}
        atomic_write_json(path, data)
