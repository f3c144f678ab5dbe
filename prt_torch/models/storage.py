"""Storage accounting of visibility models, as in seed 000 Table 1.

For each model: ``bytes`` = the real byte size of every array ``models/<kind>.pt`` stores (the
packed state of :func:`prt_torch.models.packed_state`: no basis padding; the int32 gather index
and the small regressor padding included), ``compact_bytes`` =
4 bytes per number a packed float32 store needs (real, unpadded parameters only), and each as a
percentage of the training data (``ptd``: the ``(F_train, V, C)`` float32 visibility) and of a
single mesh's PRT (``psm``: one ``(V, C)`` float32 frame). A row ``unreduced_linear`` gives the
seed's "no reduction" reference, ``(A + 1) V C`` floats.
"""

from __future__ import annotations

from typing import Any

import torch

from prt_torch.errors import check


def state_bytes(model: torch.nn.Module) -> int:
    """Sum of ``numel * element_size`` over the stored (packed) state of a visibility model, or the
    state dict of any other module."""
    from prt_torch.models.visibility import VisibilityModel, packed_state

    state = packed_state(model) if isinstance(model, VisibilityModel) else model.state_dict()
    return int(sum(t.numel() * t.element_size() for t in state.values()))


def compact_floats(model: Any) -> int:
    """Number of real (unpadded) parameters of a :class:`prt_torch.models.VisibilityModel`."""
    inp, out, reg = model.inp, model.out, model.regressor
    n = inp.mean.numel() + inp.proj.numel() + out.mean.numel()
    if out.basis.ndim == 2:  # global output PCA: (k, V) basis shared by the coefficients, mean (V,)
        n += out.basis.numel() - out.mean.numel() + out.n_vertices
        dims = torch.tensor([reg.width])
    else:
        g, _, lmax = out.basis.shape
        real_rows = (out.basis.abs().sum(-1) > 0)  # (G, Kmax)
        dims = real_rows.sum(-1)  # (G,)
        sizes = torch.bincount(out.gather.long() // lmax, minlength=g)  # (G,) V_g * C
        n += int((dims * sizes).sum())
    if model.kind == "mlp":
        d = reg.hidden_weight.shape[2]
        used = reg.out_weight.abs().sum(1) > 0  # (G, N)
        nn_ = used.sum(-1)
        n += int((nn_ * (d + 1) + dims * (nn_ + 1)).sum())
    else:
        n += int((dims * (reg.feature_dim + 1)).sum())
    return int(n)


def storage_table(models: dict[str, Any], n_train_frames: int) -> dict[str, dict[str, float]]:
    """``{kind: {bytes, compact_bytes, ptd, psm, ptd_compact, psm_compact}}`` plus
    ``unreduced_linear``; percentages are in percent."""
    check(len(models) > 0, "storage table: no models")
    check(n_train_frames > 0, f"storage table: need > 0 training frames, got {n_train_frames}")
    any_model = next(iter(models.values()))
    v, c, a = any_model.n_vertices, any_model.n_coeffs, any_model.n_features
    mesh = 4 * v * c
    data = mesh * n_train_frames

    def row(b: int, cb: int) -> dict[str, float]:
        return {"bytes": int(b), "compact_bytes": int(cb), "ptd": 100.0 * b / data, "psm": 100.0 * b / mesh,
                "ptd_compact": 100.0 * cb / data, "psm_compact": 100.0 * cb / mesh}

    table = {kind: row(state_bytes(m), 4 * compact_floats(m)) for kind, m in models.items()}
    unreduced = 4 * (a + 1) * v * c
    table["unreduced_linear"] = row(unreduced, unreduced)
    table["_reference"] = {"training_data_bytes": data, "single_mesh_bytes": mesh, "train_frames": n_train_frames,
                           "n_vertices": v, "n_coeffs": c, "n_features": a}
    return table


def storage_markdown(table: dict[str, dict[str, float]]) -> str:
    """The table as Markdown (seed 000 Table 1 layout)."""
    lines = ["| model | bytes (stored) | PTD % | PSM % | bytes (packed) | PTD % | PSM % |",
             "| --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for kind, r in table.items():
        if kind.startswith("_"):
            continue
        lines.append(f"| {kind} | {r['bytes']:,} | {r['ptd']:.3f} | {r['psm']:.1f} | {r['compact_bytes']:,} | "
                     f"{r['ptd_compact']:.3f} | {r['psm_compact']:.1f} |")
    return "\n".join(lines) + "\n"
