"""The end-to-end pose -> SH visibility model and its files.

``VisibilityModel``: pose features ``x (B, A)`` -> input PCA ``X (B, d)`` -> regressor
``Z (B, G, Kmax)`` -> per-cluster output PCA unprojection -> visibility ``(B, V, C)``
(``C = order**2``, local vertex frame, see docs/DESIGN.md). float32, dense matmuls, one gather:
ONNX-exportable with a dynamic batch axis.

Files (run directory ``runs/NAME``): ``models/<kind>.pt`` per kind, ``model.pt`` (the default
kind), ``model.json`` (metadata). A ``.pt`` file is ``torch.save`` of a plain dict
``{"format", "kind", "config", "state_dict"}`` (no pickled classes), written atomically and read
with ``torch.load(weights_only=True)``; :func:`load_model` needs nothing but that file.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import torch
from torch import nn

from prt_torch.errors import PrtError, check
from prt_torch.io import atomic_path
from prt_torch.models.projection import GlobalUnprojection, InputProjection, OutputUnprojection
from prt_torch.models.regressors import REGRESSORS

FORMAT = "prt_torch.visibility_model/1"
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


def save_model(model: VisibilityModel, path: str | Path) -> None:
    """Write ``model`` to ``path`` (``.pt``) atomically as state dict + config."""
    state = {k: t.detach().to("cpu").contiguous() for k, t in model.state_dict().items()}
    payload = {"format": FORMAT, "kind": model.kind, "config": model.config(), "state_dict": state}
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)


def load_model_file(path: str | Path) -> VisibilityModel:
    """Read one ``.pt`` model file (float32, eval mode)."""
    path = Path(path)
    if not path.is_file():
        raise PrtError(f"model file not found: {path}")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - any unpickling problem is a bad file
        raise PrtError(f"{path}: not a prt_torch model file ({type(exc).__name__})") from None
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise PrtError(f"{path}: not a prt_torch model file (format {payload.get('format')!r})"
                       if isinstance(payload, dict) else f"{path}: not a prt_torch model file")
    model = VisibilityModel.from_config(payload["config"])
    model.load_state_dict(payload["state_dict"])
    return model.float().eval()


def model_path(run_dir: str | Path, kind: str | None = None) -> Path:
    """``run_dir/model.pt`` for ``kind=None``, else ``run_dir/models/<kind>.pt``."""
    run_dir = Path(run_dir)
    if kind is None:
        return run_dir / "model.pt"
    check(kind in KINDS, f"unknown model kind '{kind}' (expected one of {list(KINDS)})")
    return run_dir / "models" / f"{kind}.pt"


def load_model(run_dir: str | Path, kind: str | None = None) -> VisibilityModel:
    """The trained model of a run: ``kind=None`` gives the default (``model.pt``, the MLP when
    trained). float32, eval mode, no dataset needed."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise PrtError(f"run directory not found: {run_dir}")
    path = model_path(run_dir, kind)
    if not path.is_file():
        raise PrtError(f"no trained {'default' if kind is None else kind} model in {run_dir} ({path.name} missing)")
    return load_model_file(path)


def load_metadata(run_dir: str | Path) -> dict[str, Any]:
    """``run_dir/model.json`` as a dict."""
    path = Path(run_dir) / "model.json"
    if not path.is_file():
        raise PrtError(f"model metadata not found: {path}")
    return json.loads(path.read_text())
