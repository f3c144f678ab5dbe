"""``prt play RUN --renderer transfer``: the player shading with seed 000's learned transfer (+ subsurface).

:class:`TransferPlayer` is a :class:`~prt_torch.player.player.Player` (same posing, camera, tone map, mesh renderer,
video/PNG writers and timings) whose radiance per frame is the run's exported transfer graph
(``transfer.onnx``, :mod:`prt_torch.transfer.graph`, listed in ``export.json`` ``transfer``): onnxruntime
evaluates ``pose -> t (V, C6) [, t_sss]`` and the dot products ``L . t`` [``L . t_sss``] with the player's lighting
(``--env`` or the procedural sky, as world-frame SH of the run's order, rotated by ``--light-angle``), and only the
``(V, 3)`` radiance outputs leave the session; numpy colours them by the shared rule
:func:`prt_torch.transfer.shading.transfer_shading` (``albedo * (L . t) + albedo / mean(albedo) * (L . t_sss)``,
``albedo`` the current BRDF's RPO tint: the rule of ``prt compare``'s ``learned_transfer``). A diffuse transfer has
no view dependence: a glossy BRDF shades as its diffuse stand-in of the same tint.

numpy + onnxruntime only: this path never imports torch.
"""

from __future__ import annotations

import os
import time
from typing import Any

import numpy as np

from prt_torch.errors import PrtError, check
from prt_torch.player.player import Player
from prt_torch.player.timing import FrameTimer
from prt_torch.rundir import RunDir
from prt_torch.runtime.session import OrtGraph
from prt_torch.shapes import check_shape
from prt_torch.transfer.shading import ARRAYS, light_input, radiance_output, transfer_shading


class TransferPlayer(Player):
    """A :class:`Player` shading with the run's learned transfer graph (module docstring).

    Args:
        run_dir: an exported run whose export has the transfer graph (trained with ``train.transfer``).
        env, brdf, threads, window_size, exposure, n_lobes, blas_threads, spinning, device: as :class:`Player`.
    """

    def __init__(self, run_dir: str | os.PathLike[str] | RunDir, env: str | os.PathLike[str] | None = None,
                 brdf: str | None = None, threads: int = 2, window_size: tuple[int, int] = (480, 640),
                 device: str = "cpu", spinning: bool = False, **kw: Any) -> None:
        from prt_torch.transfer.shading import exported_transfer

        run = RunDir.of(run_dir)
        run.export_meta()  # verified: every file it lists, the transfer graph included (one line when not)
        entry = exported_transfer(run)  # None: no transfer graph, or one of an older training
        if entry is None:
            raise PrtError(f"--renderer transfer: {run.path} has no current learned transfer graph: train with a "
                           f"`train.transfer` section, then `prt export {run.path}`")
        kw.pop("graph", None)
        super().__init__(run, env=env, brdf=brdf, graph="split", threads=threads, window_size=window_size,
                         device=device, spinning=spinning, **kw)
        path = run.inside(entry["file"])
        check(path is not None and path.is_file(), f"{run.path}: transfer graph {entry['file']!r} missing")
        self.transfer_graph = OrtGraph(path, threads=threads, spinning=spinning, device=device)
        self.arrays = [a for a in ARRAYS if a in self.transfer_graph.outputs]
        self._outputs = [radiance_output(a) for a in self.arrays]
        self.n_light = int(entry.get("n_light", self.order**2))
        check(self.transfer_graph.inputs.get("light", (None,))[0] == self.n_light,
              f"{path.name}: its light input is not ({self.n_light}, 3)")
        self.graph = "transfer"

    def light_sh(self) -> np.ndarray:
        """``(n_light, 3)`` float32 world-frame SH lighting: the player's, rotated by :attr:`light_angle`
        (zero-padded / cut to the graph's ``n_light``)."""
        lit = self.lighting.rotated_about_z(self.light_angle) if self.light_angle else self.lighting
        return light_input(lit.sh, self.n_light)

    def transfer_radiance(self, features: np.ndarray) -> list[np.ndarray]:
        """``[L . t, (L . t_sss)]`` ``(B, V, 3)`` of pose features ``(B, A)`` (only these outputs are fetched)."""
        feats = np.ascontiguousarray(features, dtype=np.float32)
        check_shape(feats, ("B", self.bundle.n_features), name="pose features")
        return self.transfer_graph.session.run(self._outputs, {"pose": feats, "light": self.light_sh()})

    def shade(self, state: Any, visibility: np.ndarray | None = None, checked: bool = True,
              timer: FrameTimer | None = None, rpo: Any = None) -> np.ndarray:
        """Radiance ``(B, V, 3)`` float32 of the posed batch: the transfer graph, coloured by the shared rule."""
        if visibility is not None:
            raise PrtError("the transfer renderer predicts its own transfer; it takes no visibility input")
        t0 = time.perf_counter()
        outs = self.transfer_radiance(state.features)
        tint = (self.rpo if rpo is None else rpo).tint
        out = transfer_shading(outs[0], {"x": tint}, outs[1] if len(outs) > 1 else None)["x"]
        if timer is not None:
            timer.add("shading", time.perf_counter() - t0)  # the compute-path step name
        return out

    def compute(self, local: np.ndarray, timer: FrameTimer | None = None) -> tuple[Any, np.ndarray]:
        t0 = time.perf_counter()
        state = self.pose(local)
        if timer is not None:
            timer.add("pose", time.perf_counter() - t0)
        return state, self.shade(state, timer=timer)
