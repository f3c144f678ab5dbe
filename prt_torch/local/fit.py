"""Fitting the local visibility models (:mod:`prt_torch.local.models`) of a deformable run (``train.local``).

* ``linear``: ``v_i = m_i + x_i W`` minimising ``sum_{f,i} |y_fi - m_i - x_fi W|^2 + alpha N tr(x'x)/D |W|^2``
  over all (frame, vertex) samples (``N`` of them, ``D = 3 S`` inputs): closed form. With per-vertex
  intercepts the normal equations are those of the per-vertex-centred data: ``W = (Xc'Xc + lam I)^-1 Xc'Yc``,
  ``m_i = ybar_i - xbar_i W``; ``X'X`` and the per-vertex sums are accumulated frame by frame in float64.
* ``mlp``: tanh layers, Adam on random (frame, vertex) samples (every vertex of every training frame is a sample:
  millions of them, where L-BFGS's full-batch steps would not fit), cosine learning-rate decay, seeded. Inputs
  and the rest terms (rest offsets in the rest frame, rest position) are standardised for the fit and folded into
  the first layer afterwards; the target is the visibility minus the per-vertex training mean ``m_i``.

The per-vertex tables (``m``, and the MLP's first-layer term ``c``) are rounded to float16 values at the end of
either fit (:func:`to_fp16_grid`), so ``prt export`` stores them in float16 losslessly.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import torch

from prt_torch.errors import check
from prt_torch.fit.config import LocalConfig
from prt_torch.fit.stages import FitHook
from prt_torch.local.models import LocalVisibility, local_offsets, neighbour_pattern, sample_offsets

#: frames per chunk when accumulating the linear normal equations / predicting
CHUNK = 8
#: version of the fitting code in each local model's key (2: per-vertex tables on the float16 grid)
LOCAL_FIT_VERSION = 2


def to_fp16_grid(x: torch.Tensor) -> torch.Tensor:
    """``x`` rounded to the nearest float16 value, kept in float32: the per-vertex tables (first-layer term,
    intercepts: most of a local model's bytes) are fitted in float32 and rounded once at the end, so the export
    stores them in float16 with no parity loss (relative rounding <= 2^-11, far below the model's error)."""
    return x.detach().to(torch.float16).to(torch.float32)


def _meta(cfg: LocalConfig, kind: str) -> dict[str, Any]:
    return {"radii": list(cfg.radii), "angles": int(cfg.angles), "hidden": list(cfg.hidden) if kind == "mlp" else [],
            "steps": int(cfg.steps) if kind == "mlp" else 0}


def fit_local_linear(positions: np.ndarray, frames: np.ndarray, visibility: np.ndarray, neighbours: np.ndarray,
                     cfg: LocalConfig) -> LocalVisibility:
    """Closed-form ridge with per-vertex intercepts (module doc). ``positions (F, V, 3)``, ``frames (F, V, 3, 3)``,
    ``visibility (F, V, C)`` float32; ``neighbours (V, S)``."""
    F, V, C = visibility.shape
    nb = torch.as_tensor(neighbours)
    D = 3 * nb.shape[1]
    xtx = np.zeros((D, D))
    xty = np.zeros((D, C))
    sx = np.zeros((V, D))
    sy = np.zeros((V, C))
    for s in range(0, F, CHUNK):
        x = local_offsets(torch.from_numpy(positions[s:s + CHUNK]), torch.from_numpy(frames[s:s + CHUNK]),
                          nb).double().numpy()  # (b, V, D)
        y = visibility[s:s + CHUNK].astype(np.float64)
        xtx += np.einsum("bvd,bve->de", x, x, optimize=True)
        xty += np.einsum("bvd,bvc->dc", x, y, optimize=True)
        sx += x.sum(0)
        sy += y.sum(0)
    xbar, ybar = sx / F, sy / F
    xtx -= F * xbar.T @ xbar  # centred per vertex
    xty -= F * xbar.T @ ybar
    lam = cfg.alpha * np.trace(xtx) / D
    w = np.linalg.solve(xtx + lam * np.eye(D), xty)
    mean = to_fp16_grid(torch.from_numpy(ybar - xbar @ w)).numpy()  # ships in float16, losslessly
    return LocalVisibility("linear", neighbours, [w], [], mean, _meta(cfg, "linear")).eval()


def rest_terms(rest: np.ndarray, rest_frames: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """``(V, 3 S + 3)``: each vertex's rest neighbourhood (:func:`local_offsets` at rest) and its rest position."""
    x = local_offsets(torch.from_numpy(np.asarray(rest, np.float32))[None],
                      torch.from_numpy(np.asarray(rest_frames, np.float32))[None], torch.as_tensor(neighbours))[0]
    return np.concatenate([x.numpy(), np.asarray(rest, np.float32)], axis=1)


def fit_local_mlp(positions: np.ndarray, frames: np.ndarray, visibility: np.ndarray, neighbours: np.ndarray,
                  rest: np.ndarray, rest_frames: np.ndarray, cfg: LocalConfig, seed: int,
                  progress: Any = None) -> LocalVisibility:
    """Adam fit of the tanh network (module doc); inputs as :func:`fit_local_linear` plus ``rest (V, 3)`` and
    ``rest_frames (V, 3, 3)`` (the per-vertex rest terms)."""
    F, V, C = visibility.shape
    gen = torch.Generator().manual_seed(int(seed))
    nb = torch.as_tensor(neighbours)
    P, Fr = torch.from_numpy(positions), torch.from_numpy(frames)
    mean = visibility.mean(axis=0, dtype=np.float64).astype(np.float32)  # (V, C)
    Y = torch.from_numpy(visibility) - torch.from_numpy(mean)
    # standardisation from a sample of the inputs; rest terms standardised over vertices
    fi = torch.randint(0, F, (min(65536, F * V),), generator=gen)
    vi = torch.randint(0, V, fi.shape, generator=gen)
    x0 = sample_offsets(P, Fr, nb, fi, vi)
    mu, sd = x0.mean(0), x0.std(0).clamp_min(1e-6)
    z = torch.from_numpy(rest_terms(rest, rest_frames, neighbours))
    zmu, zsd = z.mean(0), z.std(0).clamp_min(1e-6)
    z = (z - zmu) / zsd
    sizes = [3 * nb.shape[1], *cfg.hidden, C]
    layers = torch.nn.ModuleList(torch.nn.Linear(a, b) for a, b in zip(sizes[:-1], sizes[1:], strict=True))
    rest_in = torch.nn.Linear(z.shape[1], sizes[1], bias=False)
    with torch.no_grad():  # a deterministic init from the seeded generator
        for lin in (*layers, rest_in):
            bound = 1.0 / np.sqrt(lin.weight.shape[1])
            lin.weight.uniform_(-bound, bound, generator=gen)
            if lin.bias is not None:
                lin.bias.zero_()
    params = [*layers.parameters(), *rest_in.parameters()]
    opt = torch.optim.Adam(params, lr=cfg.lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, cfg.steps)

    def net(x: torch.Tensor, zv: torch.Tensor) -> torch.Tensor:
        h = layers[0](x) + rest_in(zv)
        for lin in layers[1:]:
            h = lin(torch.tanh(h))
        return h

    task = progress.add_task("local mlp", total=cfg.steps) if progress is not None and hasattr(progress,
                                                                                               "add_task") else None
    for step in range(cfg.steps):
        fi = torch.randint(0, F, (cfg.batch,), generator=gen)
        vi = torch.randint(0, V, (cfg.batch,), generator=gen)
        x = (sample_offsets(P, Fr, nb, fi, vi) - mu) / sd
        loss = ((net(x, z[vi]) - Y[fi, vi]) ** 2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if task is not None and (step % 50 == 0 or step == cfg.steps - 1):
            progress.update(task, completed=step + 1, description=f"local mlp (loss {float(loss.detach()):.3g})")
    last = float(loss.detach())
    check(bool(np.isfinite(last)), f"local mlp fit diverged (loss {last}); lower train.local.lr")
    with torch.no_grad():  # fold the standardisation and the rest terms into the first layer
        w0 = layers[0].weight.T / sd[:, None]  # (D, H0)
        c = layers[0].bias[None] - (mu / sd)[None] @ layers[0].weight.T + rest_in(z)  # (V, H0)
        m = torch.from_numpy(mean) + layers[-1].bias[None]
        c, m = to_fp16_grid(c), to_fp16_grid(m)  # the per-vertex tables ship in float16, losslessly
        ws = [w0, *(lin.weight.T for lin in layers[1:])]
        bs = [c, *(lin.bias for lin in layers[1:-1])]
    return LocalVisibility("mlp", neighbours, [w.detach().numpy() for w in ws], [b.detach().numpy() for b in bs],
                           m.detach().numpy(),
                           _meta(cfg, "mlp")).eval()


def fit_local(kind: str, positions: np.ndarray, frames: np.ndarray, visibility: np.ndarray, rest: np.ndarray,
              rest_frames: np.ndarray, cfg: LocalConfig, seed: int, progress: Any = None) -> tuple[LocalVisibility,
                                                                                                     float]:
    """Fit one local ``kind`` on the training frames; returns (model, seconds)."""
    F, V, C = visibility.shape
    check(positions.shape == (F, V, 3) and frames.shape == (F, V, 3, 3) and rest.shape == (V, 3),
          f"local fit needs positions (F, V, 3), frames (F, V, 3, 3), rest (V, 3) for visibility {visibility.shape}; "
          f"got {positions.shape}, {frames.shape}, {rest.shape}")
    t0 = time.perf_counter()
    nb = neighbour_pattern(rest, rest_frames, cfg.radii, cfg.angles)
    pos = np.ascontiguousarray(positions, np.float32)
    fr = np.ascontiguousarray(frames, np.float32)
    vis = np.ascontiguousarray(visibility, np.float32)
    if kind == "linear":
        model = fit_local_linear(pos, fr, vis, nb, cfg)
    else:  # big batches of one small network: every core helps (prt train pins torch to train.threads for L-BFGS)
        import os

        threads = torch.get_num_threads()
        torch.set_num_threads(max(threads, min(os.cpu_count() or 1, 8)))
        try:
            model = fit_local_mlp(pos, fr, vis, nb, rest, rest_frames, cfg, seed, progress)
        finally:
            torch.set_num_threads(threads)
    return model, time.perf_counter() - t0


def local_key(ds: Any, cfg: LocalConfig, seed: int) -> str:
    """The key a local model file records: its settings, the seed and the dataset's content key."""
    from prt_torch.rundir import stage_key

    settings = cfg.model_dump(mode="json")
    settings.pop("default")  # which kind ships is not a fit setting
    return stage_key({"local": settings, "seed": int(seed), "dataset": ds.key(), "version": LOCAL_FIT_VERSION})


def rest_geometry(ds: Any) -> tuple[np.ndarray, np.ndarray]:
    """``rest (V, 3)``, ``rest_frames (V, 3, 3)`` of a deformable dataset's subject: the character file beside
    it and the bake's frame rule (:func:`prt_torch.bake.deformable.frame_operator`)."""
    from prt_torch.bake.deformable import frame_operator
    from prt_torch.rig.character import Character
    from prt_torch.rundir import RunDir

    ch = Character.load(RunDir(ds.path).character_path)
    op = frame_operator(ch, np.asarray(ds.cluster))
    return np.asarray(ch.rest_vertices, np.float32), np.asarray(op.rest_frames, np.float32)


def train_local(ds: Any, run: Any, cfg: Any, splits: dict[str, Any], progress: Any = None) -> dict[str, Any] | None:
    """The ``train.local`` part of ``prt train`` (``cfg``: the :class:`TrainConfig`; ``splits``: its ``train`` and
    ``heldout`` :class:`~prt_torch.bake.store.SplitData`, read with ``positions`` and ``frames``): fit each local kind
    whose file is missing or stale (its recorded :func:`local_key`), write it atomically, and return the metrics
    ``{kind: {fit_s, bytes, train, heldout}}``; without ``train.local`` stale local files are removed (``None``)."""
    from prt_torch.errors import DamagedArtifact, StaleArtifact
    from prt_torch.local.models import LOCAL_KINDS, load_local, save_local
    from prt_torch.metrics import vis_rel_err

    lcfg: LocalConfig | None = cfg.local
    for k in LOCAL_KINDS:
        if lcfg is None or k not in lcfg.kinds:
            run.local_model_path(k).unlink(missing_ok=True)
    if lcfg is None:
        return None
    key = local_key(ds, lcfg, cfg.seed)
    train = splits["train"]
    rest, rest_frames = rest_geometry(ds)
    out: dict[str, Any] = {}
    for kind in lcfg.kinds:
        path = run.local_model_path(kind)
        model = None
        if path.is_file():
            try:
                old = load_local(path)
                if old.meta.get("key") == key:
                    model, fit_s = old, float(old.meta.get("fit_s", 0.0))
            except (StaleArtifact, DamagedArtifact):
                pass
        if model is None:
            if progress is not None and hasattr(progress, "console"):
                progress.console.log(f"fitting local {kind} ({train.n_frames} frames x {ds.n_vertices} vertices)")
            model, fit_s = fit_local(kind, train.extra["positions"], train.extra["frames"], train.visibility, rest,
                                     rest_frames, lcfg, cfg.seed, progress)
            model.meta.update(key=key, fit_s=fit_s)
            save_local(model, path)
        out[kind] = {"fit_s": fit_s, "bytes": int(path.stat().st_size)}
        for name, sp in splits.items():
            out[kind][name] = {"vis_rel_err": vis_rel_err(model.predict(sp.extra["positions"], sp.extra["frames"]),
                                                          sp.visibility)}
    return out


def check_dataset(ds: Any, cfg: Any) -> None:
    """``train.local`` needs a deformable (cloth) dataset: a one-line PrtError otherwise (``ds``: the
    :class:`~prt_torch.bake.store.BakedDataset`, ``cfg``: the :class:`TrainConfig`)."""
    from prt_torch.bake.deformable import is_deformable

    check(is_deformable(ds.attrs), f"{ds.path}: train.local needs a deformable (cloth) dataset")


#: ``prt train``'s ``train.local`` step (:data:`prt_torch.fit.stages.FIT_STAGES`): the local models learn from the
#: splits' ``positions`` and ``frames``
FIT_HOOK = FitHook(section="local", metrics_key="local", run=train_local, check=check_dataset,
                   extra=("positions", "frames"))
