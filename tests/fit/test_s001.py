"""The ``train.s001`` stage on a tiny baked store (tests/fit/s001_run.py): compression vs the baked matrices,
CPCA vs scikit-learn's PCA, held-out interpolation vs a trivial predictor, resumability, one-line errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from prt_torch.errors import PrtError


@pytest.fixture(scope="module")
def run(s001_run: tuple[Path, Path]) -> Path:
    return s001_run[1]


def _truth(run: Path, rows: np.ndarray) -> dict[str, np.ndarray]:
    from prt_torch.rundir import RunDir

    return RunDir(run).dataset().rows(rows, ("transfer_matrix", "frames", "pose"))


def test_cpca_with_one_cluster_is_scikit_learn_pca() -> None:
    from sklearn.decomposition import PCA

    from prt_torch.s001.fit import cpca_segment

    rng = np.random.default_rng(0)
    x = (rng.normal(size=(12, 30, 3)) @ rng.normal(size=(3, 16)) + 0.1 * rng.normal(size=(12, 30, 16)))
    x = x.astype(np.float32)
    groups = np.arange(12) // 4
    row, mean, basis, coeffs = cpca_segment(x, groups, 1, 4, 2)
    assert row.shape == (3, 30) and np.all(row == 0)
    rec = mean[0] + coeffs @ basis[0]
    ref = PCA(4).fit(x.reshape(-1, 16))
    ref_rec = ref.inverse_transform(ref.transform(x.reshape(-1, 16))).reshape(x.shape)
    assert np.sqrt(((rec - x) ** 2).mean()) == pytest.approx(np.sqrt(((ref_rec - x) ** 2).mean()), rel=1e-3)


def test_stored_sampled_poses_match_the_bake(run: Path) -> None:
    from prt_torch.rundir import RunDir
    from prt_torch.s001.player import S001Player
    from prt_torch.s001.posespace import CompressedTransfer

    data = CompressedTransfer.load(RunDir(run).s001)
    m = data.meta
    assert m["raw_bytes"] == m["n_poses"] * m["n_vertices"] * data.n_coeffs**2 * 4
    assert m["compression_ratio"] == pytest.approx(m["raw_bytes"] / data.stored_bytes()) and m["compression_ratio"] > 4
    assert data.coeff_q.dtype == np.uint16
    rows = RunDir(run).dataset().clip_rows("random")
    t = _truth(run, rows[[0, 7, 19]])
    player = S001Player(data, "s001")
    for i, j in enumerate([0, 7, 19]):
        got = player.transfer(t["pose"][i], t["frames"][i])  # at a sampled pose: exactly its stored matrices
        ref = t["transfer_matrix"][i]
        err = np.linalg.norm(got - ref) / np.linalg.norm(ref)
        assert err < 0.25, err  # the compression error (train_rel_err ~0.1 on this tiny store)
        # the segment rotation is exact: undoing it gives the stored segment-relative matrices
        d = player.rotations(t["frames"][i])[data.segment]
        np.testing.assert_allclose(np.einsum("vce,ved->vcd", got, d), data.reconstruct(j), atol=1e-4)


def test_heldout_interpolation_beats_the_mean_pose(run: Path) -> None:
    from prt_torch.rundir import RunDir
    from prt_torch.s001.player import S001Player
    from prt_torch.s001.posespace import CompressedTransfer

    ds = RunDir(run).dataset()
    data = CompressedTransfer.load(RunDir(run).s001)
    train = ds.rows(ds.clip_rows("random"), ("transfer_matrix",))["transfer_matrix"]
    mean = train.mean(axis=0)
    held = ds.split_rows("heldout")[::3]
    t = _truth(run, held)
    for scheme in ("s001", "posespace"):
        player = S001Player(data, scheme)  # type: ignore[arg-type]
        sse = sse_mean = 0.0
        for i in range(len(held)):
            got = player.transfer(t["pose"][i], t["frames"][i])
            sse += float(((got - t["transfer_matrix"][i]) ** 2).sum())
            sse_mean += float(((mean - t["transfer_matrix"][i]) ** 2).sum())
        assert sse < 0.5 * sse_mean, (scheme, sse, sse_mean)


def test_train_again_keeps_a_current_file(run: Path, s001_run: tuple[Path, Path]) -> None:
    from prt_torch.bake.store import BakedDataset
    from prt_torch.config import load_config
    from prt_torch.rundir import RunDir
    from prt_torch.s001.fit import s001_key, train_s001

    cfg = load_config(s001_run[0])
    rd = RunDir(run)
    before = rd.s001.stat().st_mtime_ns
    meta = train_s001(rd.dataset(), rd, cfg.train)
    assert meta is not None and rd.s001.stat().st_mtime_ns == before
    # the key follows the dataset's content key (a re-bake with other settings but the same frame counts refits)
    class Store:
        def __init__(self, key: str) -> None:
            self._key = key

        def __repr__(self) -> str:
            return "Store()"

        def key(self) -> str:
            return self._key

    scfg = cfg.train.s001
    assert s001_key(Store("a"), scfg) != s001_key(Store("b"), scfg)
    assert s001_key(Store("a"), scfg) == s001_key(Store("a"), scfg)
    assert s001_key(BakedDataset(rd.dataset_path), scfg) == meta["key"]


def test_bad_input_is_one_line(run: Path, synthetic_dataset: Path) -> None:
    from prt_torch.bake.store import open_dataset
    from prt_torch.fit.config import S001Config
    from prt_torch.rundir import RunDir
    from prt_torch.s001.fit import fit_s001
    from prt_torch.s001.posespace import CompressedTransfer

    skin = (np.array([-1, 0]), np.zeros((1, 1), int), np.ones((1, 1)))
    with pytest.raises(PrtError, match="transfer_matrix") as e:  # a store baked without transfer matrices
        fit_s001(open_dataset(synthetic_dataset), S001Config(), skin)
    assert "\n" not in str(e.value)
    with pytest.raises(PrtError, match="not a clip") as e:
        fit_s001(RunDir(run).dataset(), S001Config(clip="nope"), skin)
    assert "\n" not in str(e.value)
    bad = run / "broken.npz"
    bad.write_bytes(b"not an npz")
    with pytest.raises(PrtError, match="s001") as e:
        CompressedTransfer.load(bad)
    assert "\n" not in str(e.value)
