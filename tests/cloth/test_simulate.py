"""The MuJoCo cloth simulation and its vertex cache (issue 11): determinism, resume, pinning, free fall against
the closed form, wind, blow-up and bad-input errors, the cape staying outside its body's colliders.

Tiny cloths (<= 10 x 14 vertices) and a few frames keep the whole file to a few seconds of simulation.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("mujoco")

from prt_torch.cloth import simulate as S  # noqa: E402
from prt_torch.cloth.body import capsule_distance  # noqa: E402
from prt_torch.cloth.cache import VertexCache  # noqa: E402
from prt_torch.cloth.subject import ClothSubject, grid_faces  # noqa: E402
from prt_torch.config import RunConfig, config_from_dict  # noqa: E402
from prt_torch.errors import PrtError  # noqa: E402
from prt_torch.rundir import RunDir  # noqa: E402
from tests.tolerance import assert_bitwise

FPS = 30.0
G = 9.81


def flag_cfg(run_dir: Path, **cloth: Any) -> RunConfig:
    base: dict[str, Any] = {
        "scene": "flag", "rows": 8, "cols": 12, "width": 0.6, "height": 0.4, "settle_frames": 2,
        "train_winds": [{"name": "calm", "speed": 2.0, "frames": 4, "seed": 1},
                        {"name": "gusty", "speed": 5.0, "direction_deg": 30.0, "gust_amplitude": 2.0, "frames": 5}],
        "heldout_winds": [{"name": "side", "speed": 4.0, "direction_deg": 60.0, "frames": 3}],
    }
    base.update(cloth)
    return config_from_dict({"name": "flag_test", "run_dir": str(run_dir), "character": {"fps": FPS},
                             "cloth": base})


def cached(path: Path) -> dict[str, np.ndarray]:
    c = VertexCache(path)
    return {n: c.positions(n) for n in c.sequences()}


@pytest.fixture(scope="module")
def flag_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[RunConfig, dict[str, np.ndarray]]:
    cfg = flag_cfg(tmp_path_factory.mktemp("flag") / "run")
    path = S.simulate(cfg, progress=False)
    return cfg, cached(path)


def test_deterministic(flag_run: tuple[RunConfig, dict[str, np.ndarray]], tmp_path: Path) -> None:
    cfg, first = flag_run
    again = cached(S.simulate(flag_cfg(tmp_path / "again"), progress=False))
    assert list(first) == ["calm", "gusty", "side"]
    for name, pos in first.items():
        assert pos.dtype == np.float32 and pos.shape[1:] == (96, 3)
        assert_bitwise(pos, again[name], err_msg=name, why="MuJoCo's simulation run twice: the same operations")
    assert first["calm"].shape[0] == 4 and first["gusty"].shape[0] == 5 and first["side"].shape[0] == 3


def test_resume_skips_done_and_redoes_interrupted(flag_run: tuple[RunConfig, dict[str, np.ndarray]], tmp_path: Path,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    _, reference = flag_run
    cfg = flag_cfg(tmp_path / "run")
    calls: list[str] = []
    real = S.simulate_sequence

    def interrupted(subject: ClothSubject, name: str, engine: Any = None, on_frame: Any = None) -> Any:
        calls.append(name)

        def stop(done: int, total: int) -> None:
            if name == "gusty" and done == 3:
                raise KeyboardInterrupt  # killed in the middle of the second sequence
        return real(subject, name, engine, stop)

    monkeypatch.setattr(S, "simulate_sequence", interrupted)
    with pytest.raises(KeyboardInterrupt):
        S.simulate(cfg, progress=False)
    cache = VertexCache(RunDir(cfg.out_dir).simulation)
    assert cache.sequences() == ["calm"] and not cache.is_complete("gusty") and not cache.is_complete()
    with pytest.raises(PrtError, match="not simulated yet"):
        cache.positions("gusty")
    calls.clear()
    monkeypatch.setattr(S, "simulate_sequence", real)

    def counting(subject: ClothSubject, name: str, engine: Any = None, on_frame: Any = None) -> Any:
        calls.append(name)
        return real(subject, name, engine, on_frame)

    monkeypatch.setattr(S, "simulate_sequence", counting)
    S.simulate(cfg, progress=False)
    assert calls == ["gusty", "side"]  # the finished sequence is not simulated again
    resumed = cached(RunDir(cfg.out_dir).simulation)
    for name, pos in reference.items():
        assert_bitwise(pos, resumed[name], err_msg=name, why="a resumed simulation runs the same steps")
    calls.clear()
    S.simulate(cfg, progress=False)
    assert calls == []


def test_changed_config_is_refused(flag_run: tuple[RunConfig, dict[str, np.ndarray]]) -> None:
    cfg, _ = flag_run
    other = flag_cfg(cfg.out_dir, young=1.0e3)
    with pytest.raises(PrtError, match="cloth.young") as exc:
        S.simulate(other, progress=False)
    assert "\n" not in str(exc.value)
    with pytest.raises(PrtError, match="cloth.heldout_winds differs"):
        S.simulate(flag_cfg(cfg.out_dir, heldout_winds=[]), progress=False)


def test_pinned_edge_stays(flag_run: tuple[RunConfig, dict[str, np.ndarray]]) -> None:
    cfg, seqs = flag_run
    c = cfg.cloth
    pole_z = np.linspace(c.flag_top, c.flag_top - c.height, c.rows)  # the pole: x = y = 0
    for pos in seqs.values():
        pole = pos[:, :: c.cols]  # column 0 of every row
        assert np.allclose(pole[..., 0], 0.0, atol=1e-7) and np.allclose(pole[..., 1], 0.0, atol=1e-7)
        assert np.allclose(pole[..., 2], pole_z[None], atol=1e-6)
        free = np.delete(pos, np.arange(c.rows) * c.cols, axis=1)
        assert np.ptp(free, axis=0).max() > 1e-3  # the rest of the flag moves


def test_free_fall_follows_closed_form(tmp_path: Path) -> None:
    cfg = flag_cfg(tmp_path / "fall", pin_edge=False, air_density=0.0, settle_frames=0,
                   train_winds=[{"name": "drop", "speed": 0.0, "gust_amplitude": 0.0, "frames": 10}], heldout_winds=[])
    pos = cached(S.simulate(cfg, progress=False))["drop"].astype(np.float64)
    subject = ClothSubject.load(cfg)
    c0 = subject.cloth_rest.mean(axis=0)
    t = np.arange(1, 11) / FPS
    z = c0[2] - 0.5 * G * t**2
    dt = 1.0 / (FPS * cfg.cloth.substeps)
    cen = pos.mean(axis=1)
    # semi-implicit Euler lags the exact parabola by g dt t / 2
    assert np.allclose(cen[:, 2], z, atol=0.5 * G * dt * t.max() + 1e-4)
    assert np.allclose(cen[:, :2], c0[:2], atol=1e-5)


@pytest.mark.parametrize("direction", [90.0, -90.0])
def test_wind_pushes_flag_downwind(tmp_path: Path, direction: float) -> None:
    winds = [{"name": "w", "speed": 5.0, "direction_deg": direction, "gust_amplitude": 0.0, "gust_direction_deg": 0.0,
              "frames": 8}]
    cfg = flag_cfg(tmp_path / "wind", train_winds=winds, heldout_winds=[], settle_frames=0, substeps=24)
    pos = cached(S.simulate(cfg, progress=False))["w"]
    still = cached(S.simulate(flag_cfg(tmp_path / "still", heldout_winds=[], settle_frames=0, substeps=24,
                                       train_winds=[{**winds[0], "speed": 0.0}]), progress=False))["w"]
    dy = pos[-1, :, 1].mean() - still[-1, :, 1].mean()
    assert abs(still[-1, :, 1]).max() < 1e-6  # no wind: the flag stays in its plane
    assert np.sign(dy) == np.sign(np.sin(np.radians(direction))) and abs(dy) > 0.02


def test_blow_up_is_one_line(tmp_path: Path) -> None:
    cfg = flag_cfg(tmp_path / "boom", substeps=1, young=1.0e12, thickness=0.05, settle_frames=0)
    with pytest.raises(PrtError, match=r"blew up in sequence 'calm' at frame \d+") as exc:
        S.simulate(cfg, progress=False)
    assert "\n" not in str(exc.value)


def test_bad_cloth_input(tmp_path: Path) -> None:
    cfg = flag_cfg(tmp_path / "bad")
    good = ClothSubject.load(cfg)
    rest, faces = good.cloth_rest.copy(), good.cloth_faces.copy()
    rest[5, 2] = np.nan
    with pytest.raises(PrtError, match="NaN") as exc:
        ClothSubject(cfg.cloth, rest, faces, good.pinned, good.fps)
    assert "\n" not in str(exc.value)
    v = np.array([[x, 0.0, -z] for z in range(3) for x in range(3)] + [[0.5, 1.0, 0.0]], dtype=float)
    bad = np.concatenate([grid_faces(3, 3), [[0, 4, 9]]])  # a third face on the quad diagonal (0, 4)
    assert ((bad == 0).any(1) & (bad == 4).any(1)).sum() == 3
    with pytest.raises(PrtError, match="non-manifold"):
        ClothSubject(cfg.cloth, v, bad, [0], good.fps)


def test_subject_mesh_and_edges() -> None:
    r, c = 7, 5
    cfg = config_from_dict({"name": "x", "cloth": {"scene": "flag", "rows": r, "cols": c,
                                                  "train_winds": [{"name": "a"}]}})
    s = ClothSubject.load(cfg)
    assert s.character.num_vertices == r * c and s.cloth_slice == slice(0, r * c)
    assert s.character.num_joints == 1 and np.all(s.character.weights == 1)
    edges = r * (c - 1) + c * (r - 1) + (r - 1) * (c - 1)  # rows, columns, diagonals of the triangulated grid
    boundary = 2 * (r - 1) + 2 * (c - 1)
    assert s.cloth_edges.shape == (edges - boundary, 4)
    assert s.sequences("train") == ["a"] and s.sequences("heldout") == []
    n = s.character.rest_normals
    assert np.allclose(n, [0.0, 1.0, 0.0], atol=1e-6)  # faces wound toward +y


@pytest.fixture(scope="module")
def cape(tmp_path_factory: pytest.TempPathFactory) -> tuple[ClothSubject, VertexCache]:
    run = tmp_path_factory.mktemp("cape") / "run"
    cfg = config_from_dict({
        "name": "cape_test", "run_dir": str(run),
        "character": {"density": 0.1, "fps": FPS, "train_clips": [{"clip": "walk", "frames": "0:12"}],
                      "heldout_clips": [{"clip": "wave", "frames": "0:4"}]},
        "cloth": {"scene": "cape", "rows": 12, "cols": 7, "settle_frames": 8, "substeps": 24}})
    path = S.simulate(cfg, progress=False)
    return ClothSubject.load(cfg), VertexCache(path)


def test_cape_stays_outside_the_body(cape: tuple[ClothSubject, VertexCache]) -> None:
    subject, cache = cape
    assert subject.body is not None and subject.capsules is not None
    assert cache.sequences() == ["walk[0:12]", "wave[0:4]"]
    for name in cache.sequences():
        pos = cache.positions(name)
        poses = subject.body_sequence(name).poses
        body, _ = subject.body.skin_mesh(poses)
        assert_bitwise(pos[:, : subject.n_body], body, why="the body's skinned vertices, copied first")
        assert_bitwise(cache.body_features(name), poses.features, why="the cache stores the features as they are")
        cloth = pos[:, subject.cloth_slice].astype(np.float64)
        a, b = subject.capsules.posed(poses.skin)
        d = capsule_distance(cloth, a, b, subject.capsules.radius)  # (T, N), independent of MuJoCo
        assert (d < -0.01).mean() == 0.0  # no cloth vertex more than 1 cm inside a capsule
        # the top row rides on the chest: the bind-pose row carried by the anchor joint's skin matrix
        top = subject.cloth_rest[: subject.cloth.cols]
        m = poses.skin[:, subject.anchor]
        want = np.einsum("tij,nj->tni", m[:, :3, :3], top) + m[:, None, :3, 3]
        assert np.allclose(cloth[:, : subject.cloth.cols], want, atol=1e-5)
    walk = cache.positions("walk[0:12]")[:, subject.cloth_slice]
    assert np.ptp(walk[:, :, 1], axis=0).max() > 0.01  # the cape moves with the walk


def test_cache_errors(cape: tuple[ClothSubject, VertexCache], tmp_path: Path) -> None:
    _, cache = cape
    with pytest.raises(PrtError, match="no sequence 'nope'"):
        cache.positions("nope")
    with pytest.raises(PrtError, match="vertex cache not found"):
        VertexCache(tmp_path / "missing.zarr")


def test_parallel_workers_match_serial(flag_run: tuple[RunConfig, dict[str, np.ndarray]], tmp_path: Path) -> None:
    _, serial = flag_run
    cfg = flag_cfg(tmp_path / "par", workers=2)
    par = cached(S.simulate(cfg, progress=False))
    for name, pos in serial.items():
        assert_bitwise(pos, par[name], err_msg=name, why="each sequence simulates alone: parallel runs change nothing")
