"""The end-to-end pose -> SH visibility model and its files.

``VisibilityModel``: pose features ``x (B, A)`` -> input PCA ``X (B, d)`` -> regressor
``Z (B, G, Kmax)`` -> per-cluster output PCA unprojection -> visibility ``(B, V, C)``
(``C = order**2``, local vertex frame, see docs/DESIGN.md). float32, dense matmuls, one gather:
ONNX-exportable with a dynamic batch axis.

Files (run directory ``runs/NAME``): ``models/<kind>.pt`` per kind, ``model.pt`` (the default
kind: a hard link to ``models/<kind>.pt``, or a copy where links are unsupported), ``model.json``
(metadata). A ``.pt`` file is ``torch.save`` of a plain dict ``{"format", "kind", "config",
"state_dict"}`` (no pickled classes), written atomically and read with
``torch.load(weights_only=True)``; :func:`load_model` needs nothing but that file.

Stored state is packed (:func:`packed_state`): the per-cluster output basis, padded in memory to
``(G, Kmax, Lmax)`` for one batched matmul, is saved as only its real blocks
(``out.basis_packed``, cluster by cluster, each ``(K_g, V_g * C)`` row-major) with
``out.basis_dims (G,)`` = ``K_g`` and ``out.basis_lens (G,)`` = ``V_g * C`` (int32), and
re-padded on load. Files of format ``/1`` (padded) still load.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from torch import nn

from prt_torch.errors import DamagedArtifact, MissingArtifact, StaleArtifact, check
from prt_torch.io import atomic_path
from prt_torch.models.projection import GlobalUnprojection, InputProjection, OutputUnprojection
from prt_torch.models.regressors import REGRESSORS
from prt_torch.rundir import RunDir

FORMAT = "prt_torch.visibility_model/2"
READABLE_FORMATS = ("prt_torch.visibility_model/1", FORMAT)
KINDS = ("linear", "quadratic", "mlp")


class VisibilityModel(nn.Module):
    """Pose features ``(B, A)`` float32 -> SH visibility ``(B, V, C)`` float32.

    Attributes: ``kind`` (``linear`` | ``quadratic`` | ``mlp``), ``n_features`` (A),
    ``n_vertices`` (V), ``n_coeffs`` (C), ``order`` (n, ``C = n*n``); submodules ``inp``
    (:class:`InputProjection`), ``regressor`` and ``out`` (:class:`OutputUnprojection`).
    """

    def __init__(self, kind: str, inp: InputProjection, regressor: nn.Module,
                 out: OutputUnprojection | GlobalUnprojection) -> None:
        super().__init__()
        check(kind in REGRESSORS, f"unknown model kind '{kind}' (expected one of {sorted(REGRESSORS)})")
        self.kind = kind
        self.inp = inp
        self.regressor = regressor
        self.out = out

    @property
    def n_features(self) -> int:
        return self.inp.in_dim

    @property
    def n_vertices(self) -> int:
        return self.out.n_vertices

    @property
    def n_coeffs(self) -> int:
        return self.out.n_coeffs

    @property
    def order(self) -> int:
        return int(round(self.n_coeffs**0.5))

    def forward(self, pose: torch.Tensor) -> torch.Tensor:
        return self.out(self.regressor(self.inp(pose)))

    @torch.no_grad()
    def predict(self, pose: Any, batch: int = 256) -> torch.Tensor:
        """Checked, batched inference on any array-like ``(B, A)`` -> ``(B, V, C)`` float32 tensor."""
        x = torch.as_tensor(pose, dtype=torch.float32)
        check(x.ndim == 2 and x.shape[1] == self.n_features,
              f"pose features: expected shape (B, {self.n_features}), got {tuple(x.shape)}")
        check(bool(torch.isfinite(x).all()), "pose features contain NaN or Inf")
        return torch.cat([self(x[i:i + batch]) for i in range(0, x.shape[0], batch)], dim=0) \
            if x.shape[0] else torch.zeros(0, self.n_vertices, self.n_coeffs)

    def config(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "regressor": self.regressor.config(),
            "n_features": self.n_features,
            "reduced_inputs": self.inp.out_dim,
            "n_vertices": self.n_vertices,
            "n_coeffs": self.n_coeffs,
            "basis_shape": list(self.out.basis.shape),
            "output": "global" if isinstance(self.out, GlobalUnprojection) else "cluster",
        }

    @classmethod
    def from_config(cls, config: dict[str, Any]) -> VisibilityModel:
        """An uninitialised model with the shapes of ``config`` (fill with ``load_state_dict``)."""
        kind = config["kind"]
        check(kind in REGRESSORS, f"unknown model kind '{kind}'")
        a, d = int(config["n_features"]), int(config["reduced_inputs"])
        v, c = int(config["n_vertices"]), int(config["n_coeffs"])
        inp = InputProjection(torch.zeros(a), torch.zeros(a, d))
        out: OutputUnprojection | GlobalUnprojection
        if config.get("output", "cluster") == "global":
            k, _ = (int(s) for s in config["basis_shape"])
            out = GlobalUnprojection(torch.zeros(k, v), torch.zeros(v * c), v, c)
        else:
            g, k, lmax = (int(s) for s in config["basis_shape"])
            out = OutputUnprojection(torch.zeros(g, k, lmax), torch.zeros(v * c, dtype=torch.int32),
                                     torch.zeros(v * c), v, c)
        reg = REGRESSORS[kind](**config["regressor"])
        return cls(kind, inp, reg, out)


def _basis_extent(out: OutputUnprojection) -> tuple[torch.Tensor, torch.Tensor]:
    """``(G,)`` real component rows ``K_g`` and real columns ``V_g * C`` of a padded cluster basis."""
    g, _, lmax = out.basis.shape
    dims = (out.basis.abs().sum(-1) > 0).sum(-1)  # rows are zero only as padding (scaled PCA components)
    lens = torch.bincount(out.gather.long() // lmax, minlength=g)
    return dims.to(torch.int32), lens.to(torch.int32)


def packed_state(model: VisibilityModel) -> dict[str, torch.Tensor]:
    """The state dict as stored: the per-cluster basis without its zero padding (see module doc)."""
    state = {k: t.detach().to("cpu").contiguous() for k, t in model.state_dict().items()}
    if isinstance(model.out, OutputUnprojection):
        basis = state.pop("out.basis")  # (G, Kmax, Lmax)
        dims, lens = _basis_extent(model.out)
        blocks = [basis[g, : int(dims[g]), : int(lens[g])].reshape(-1) for g in range(basis.shape[0])]
        state["out.basis_packed"] = torch.cat(blocks).contiguous()
        state["out.basis_dims"] = dims
        state["out.basis_lens"] = lens
    return state


def _unpack_state(state: dict[str, torch.Tensor], basis_shape: list[int], path: Path) -> dict[str, torch.Tensor]:
    """Inverse of :func:`packed_state` (a padded ``/1`` state passes through)."""
    if "out.basis_packed" not in state:
        return state
    state = dict(state)
    flat = state.pop("out.basis_packed")
    dims, lens = state.pop("out.basis_dims").long(), state.pop("out.basis_lens").long()
    g, k, lmax = (int(s) for s in basis_shape)
    check(dims.shape == (g,) and lens.shape == (g,) and int(dims.max()) <= k and int(lens.max()) <= lmax
          and int((dims * lens).sum()) == flat.numel(), f"{path}: packed output basis does not match its shape")
    basis = torch.zeros(g, k, lmax, dtype=flat.dtype)
    offsets = torch.cumsum(dims * lens, 0) - dims * lens
    for i in range(g):
        n, m, o = int(dims[i]), int(lens[i]), int(offsets[i])
        basis[i, :n, :m] = flat[o:o + n * m].reshape(n, m)
    state["out.basis"] = basis
    return state


def save_model(model: VisibilityModel, path: str | Path) -> None:
    """Write ``model`` to ``path`` (``.pt``) atomically as packed state dict + config."""
    state = packed_state(model)
    payload = {"format": FORMAT, "kind": model.kind, "config": model.config(), "state_dict": state}
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)


def read_payload(path: str | Path, formats: tuple[str, ...], what: str = "model file") -> dict[str, Any]:
    """The dict a ``.pt`` model file holds (tensors only: ``weights_only``), its ``format`` one of ``formats``;
    one-line :class:`PrtError` naming ``what`` for a missing, unreadable or foreign file."""
    path = Path(path)
    if not path.is_file():
        raise MissingArtifact(f"{what} not found: {path}")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - any unpickling problem is a bad file
        raise DamagedArtifact(f"{path}: not a prt_torch {what} ({type(exc).__name__})") from None
    if not isinstance(payload, dict) or payload.get("format") not in formats:
        fmt = payload.get("format") if isinstance(payload, dict) else None
        ours = isinstance(fmt, str) and any(fmt.split("/")[0] == f.split("/")[0] for f in formats)
        raise (StaleArtifact if ours else DamagedArtifact)(
            f"{path}: not a prt_torch {what} (format {payload.get('format')!r})" if isinstance(payload, dict)
            else f"{path}: not a prt_torch {what}")
    return payload


def load_model_file(path: str | Path) -> VisibilityModel:
    """Read one ``.pt`` model file (float32, eval mode)."""
    path = Path(path)
    payload = read_payload(path, READABLE_FORMATS)
    model = VisibilityModel.from_config(payload["config"])
    state = payload["state_dict"]
    if payload["config"].get("output", "cluster") == "cluster":
        state = _unpack_state(state, payload["config"]["basis_shape"], path)
    model.load_state_dict(state)
    return model.float().eval()


def link_default(run_dir: str | Path | RunDir, kind: str) -> Path:
    """Make the run's default model file a hard link to the ``kind`` file (atomic replace; a copy where
    the file system has no hard links). Returns its path."""
    import os
    import shutil

    run = RunDir.of(run_dir)
    src, dst = model_path(run, kind), run.model_path()
    check(src.is_file(), f"no trained {kind} model in {run.path} ({src.name} missing)")
    with atomic_path(dst) as tmp:
        try:
            tmp.unlink()
            os.link(src, tmp)
        except OSError:
            shutil.copyfile(src, tmp)
    return dst


def model_path(run_dir: str | Path | RunDir, kind: str | None = None) -> Path:
    """The default model file for ``kind=None``, else the ``kind`` file (:meth:`RunDir.model_path`)."""
    if kind is not None:
        check(kind in KINDS, f"unknown model kind '{kind}' (expected one of {list(KINDS)})")
    return RunDir.of(run_dir).model_path(kind)


def load_model(run_dir: str | Path | RunDir, kind: str | None = None) -> VisibilityModel:
    """The trained model of a run: ``kind=None`` gives the default (the MLP when trained). float32, eval
    mode, no dataset needed. The run's ``model.json`` must record the file's sha256 (:meth:`RunDir.model_meta`
    verifies the whole train unit): a model file of an interrupted ``prt train`` is refused with one line."""
    run = RunDir.of(run_dir).require()
    path = model_path(run, kind)
    if not path.is_file():
        raise MissingArtifact(f"no trained {'default' if kind is None else kind} model in {run.path} "
                              f"({path.name} missing)")
    meta = run.model_meta()  # the train unit's commit record: every model file has its recorded sha256
    if kind is not None and kind not in meta["kinds"]:
        raise StaleArtifact(f"{run.model_json}: this run's last training has no {kind} model (kinds {meta['kinds']})")
    return load_model_file(path)


def load_metadata(run_dir: str | Path | RunDir) -> dict[str, Any]:
    """The run's model metadata (:meth:`RunDir.model_meta`)."""
    return RunDir.of(run_dir).model_meta()
