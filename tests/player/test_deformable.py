"""The deformable player (prt_torch.cloth.player): frames, shading, no torch, bad input."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from prt_torch.errors import PrtError
from tests.player.deformable_run import (
    FRAMES,
    N_CLIPS,
    body_features,
    build_deformable_run,
    flag_mesh,
    heldout_positions,
)


@pytest.fixture(scope="session")
def deformable_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object]:
    return build_deformable_run(tmp_path_factory.getbasetemp())


@pytest.fixture(scope="module")
def player(deformable_run):
    from prt_torch.cloth.player import DeformablePlayer

    p = DeformablePlayer(deformable_run[0], brdf="phong")
    yield p
    p.close()


def test_frames_equal_the_frame_operator(player, deformable_run) -> None:
    """The player's vertex-last float32 frames == FrameOperator.frames (float64 reference) of the same positions,
    and its normals are their n rows."""
    from prt_torch.deform.frames import FrameOperator

    rest, faces = flag_mesh()
    op = FrameOperator.from_rest(rest, faces, player.deform.operator.labels)
    pos = heldout_positions()[::5]
    state = player.frames(np.ascontiguousarray(pos.transpose(0, 2, 1)))
    np.testing.assert_allclose(state.frames_vx33(), op.frames(pos), atol=2e-5)
    np.testing.assert_allclose(state.normals.transpose(0, 2, 1), op.frames(pos)[:, :, 2], atol=2e-5)
    np.testing.assert_allclose(state.positions_vx3(0), pos[0])


def test_played_radiance_equals_the_shipping_shader(player) -> None:
    """A played frame's radiance == prt_torch.scoring.shading's RPO shading (torch, the compare yardstick) of the same
    visibility, frames, camera, lobes and RPO."""
    from prt_torch.brdf.rpo import RPO
    from prt_torch.scoring.shading import ShippingShader

    pos = heldout_positions()[7:9]
    state, rad = player.compute_positions(pos)
    vis = player.visibility_from_positions(pos)
    rpo = RPO.load(player.bundle.run.rpo_path("phong"))
    shader = ShippingShader({"sky": player.lighting}, {"phong": rpo}, player.eye, paths=("lobes",))
    ref = shader.shade_chunk({"m": vis}, state.frames_vx33(), pos)[("sky", "phong", "lobes")]["m"]
    assert rad.shape == ref.shape == (2, pos.shape[1], 3)
    assert float(np.abs(rad - ref).max() / np.abs(ref).max()) < 1e-4


@pytest.mark.parametrize("mode,features", [("fused", "numpy"), ("fused", "graph"), ("overlap", "numpy"),
                                           ("overlap", "graph")])
def test_graph_modes_agree(player, deformable_run, mode: str, features: str) -> None:
    """split (numpy features, pose graph, shading graph: the default) == the fused graphs (cluster order:
    fused.onnx on the numpy features, positions_fused.onnx on the positions) == the overlapped split path (either
    features)."""
    from prt_torch.cloth.player import DeformablePlayer

    assert player.mode == "split" and player.vertex_order is not None
    pos = heldout_positions()[3:4]
    _, a = player.compute_positions(pos)
    p2 = DeformablePlayer(deformable_run[0], brdf="phong", graph=mode, features=features)
    try:
        assert (p2.positions_fused is not None) == (mode == "fused" and features == "graph")
        _, b = p2.compute_positions(pos)
    finally:
        p2.close()
    np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5)


def test_pipeline_stream_equals_split_frame_by_frame(player, deformable_run, tmp_path: Path) -> None:
    """The pipelined playback (frame i + 1's stage on the worker while frame i is shaded) gives every frame's state
    and radiance of the split path, in order, for every prefix length (0, 1 and the whole sequence); a single frame
    through compute() is the split path too; play() in pipeline mode writes a full timings file."""
    from prt_torch.cloth.player import DeformablePlayer

    seq = player.make_sequence(heldout_positions()[:9], name="held")
    ref = [(s.frames.copy(), r) for s, r in player.compute_stream(seq, len(seq))]
    p2 = DeformablePlayer(deformable_run[0], brdf="phong", graph="pipeline")
    try:
        assert p2.bundle.graphs["shading"].threads == 1  # two stages, one onnxruntime thread each
        for n in (0, 1, len(seq)):
            got = [(s.frames.copy(), r) for s, r in p2.compute_stream(seq, n)]
            assert len(got) == n
            for (fa, ra), (fb, rb) in zip(ref[:n], got, strict=True):
                np.testing.assert_allclose(fb, fa, rtol=0, atol=1e-6)
                np.testing.assert_allclose(rb, ra, rtol=1e-5, atol=1e-6)
        _, one = p2.compute(seq[4:5])
        np.testing.assert_allclose(one, ref[4][1], rtol=1e-5, atol=1e-6)
        res = p2.play(seq, max_frames=6, timings=tmp_path / "pipe.json", progress=False)
    finally:
        p2.close()
    t = json.loads((tmp_path / "pipe.json").read_text())
    assert res.frames == 6 and all(len(v) == 6 for v in t["frames_ms"].values())
    assert set(t["frames_ms"]) >= {"visibility", "shading"} and res.summary["compute_fps"] > 0


@pytest.fixture(scope="session")
def body_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object]:
    return build_deformable_run(tmp_path_factory.getbasetemp(), name="deformable_body_run", n_body=5)


def test_body_features_play_alike_in_every_mode(body_run) -> None:
    """A run with body features after the dihedral angles (the cape's append_pose): split, pipeline, overlap and both
    fused graphs give the same radiance for the same positions and body features; other body features give other
    radiance (they reach the model); a sequence without them is a one-line error."""
    from prt_torch.cloth.player import DeformablePlayer

    n_body = 5
    pos = heldout_positions()[:6]
    body = body_features(FRAMES, n_body, seed=N_CLIPS - 1)[:6]
    split = DeformablePlayer(body_run[0], brdf="phong")
    try:
        assert split.n_body == n_body
        ref = [r for _, r in split.compute_stream(split.make_sequence(pos, body), len(pos))]
        for mode, features in (("pipeline", "numpy"), ("pipeline", "graph"), ("overlap", "graph"), ("fused", "numpy"),
                               ("fused", "graph")):
            q = DeformablePlayer(body_run[0], brdf="phong", graph=mode, features=features)
            try:
                got = [r for _, r in q.compute_stream(q.make_sequence(pos, body), len(pos))]
            finally:
                q.close()
            for a, b in zip(ref, got, strict=True):
                np.testing.assert_allclose(b, a, rtol=1e-4, atol=1e-5, err_msg=f"{mode}/{features}")
        other = [r for _, r in split.compute_stream(split.make_sequence(pos, body[::-1].copy()), len(pos))]
        assert max(float(np.abs(a - b).max()) for a, b in zip(ref, other, strict=True)) > 1e-3
        with pytest.raises(PrtError, match="body features"):
            split.make_sequence(pos, None)
    finally:
        split.close()


def test_numpy_features_equal_the_positions_graph(player, deformable_run) -> None:
    """The default visibility step (numpy dihedral angles + the pose graph) == the shipped positions graph (ORT,
    features in the graph) and the features == the numpy rule cloth_features; whole frames agree across the two
    feature modes."""
    from prt_torch.cloth.inputs import cloth_features
    from prt_torch.cloth.player import DeformablePlayer

    assert player.features == "numpy"
    pos = heldout_positions()[4:7]
    soa = np.ascontiguousarray(pos.transpose(0, 2, 1))
    ref_f = cloth_features(pos.astype(np.float64), deformable_run[1].edges, None)
    np.testing.assert_allclose(player.pose_features(soa), ref_f, atol=1e-4)
    vis = player._visibility_numpy(soa, None)
    ref = player.visibility_from_positions(pos)
    np.testing.assert_allclose(vis, ref, atol=1e-5 * float(np.abs(ref).max()))
    p2 = DeformablePlayer(deformable_run[0], brdf="phong", features="graph")
    try:
        _, a = player.compute_positions(pos)
        _, b = p2.compute_positions(pos)
    finally:
        p2.close()
    np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5)
    with pytest.raises(PrtError, match="features mode"):
        DeformablePlayer(deformable_run[0], features="torch")


def test_bench_play_deformable_ratios(deformable_run, capsys: pytest.CaptureFixture[str]) -> None:
    """`prt bench play` on a deformable export: every variant timed, and each reported ratio is the quotient of the
    medians it names (new / old, side by side)."""
    from prt_torch.cli import main

    rc = main(["bench", "play", str(deformable_run[0]), "--frames", "5", "--repeats", "1", "--warmup", "1",
               "--precisions", "int8", "--json"])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    ms, r = out["steps_ms"], out["ratios"]
    assert set(out["fps_variants"]) >= {"frame_split", "frame_split_graphfeat", "frame_overlap", "frame_fused",
                                        "stream_pipeline"}
    assert r["sequence playback: pipeline / split"] == pytest.approx(ms["stream_pipeline"] / ms["stream_split"])
    assert out["fps_pipeline"] == pytest.approx(1e3 / ms["stream_pipeline"])
    assert r["frame split: numpy features / graph features"] == pytest.approx(
        ms["frame_split"] / ms["frame_split_graphfeat"])
    assert out["fps"] == pytest.approx(1e3 / min(ms[k] for k in ("frame_split", "frame_overlap", "frame_fused")))
    assert all(v > 0 for v in r.values())


def test_play_writes_video_and_timings(player, tmp_path: Path) -> None:
    """play() writes the video and the timings. It aims the camera at the sequence (frame_sequence), which moves the
    eye the shared module player's other tests shade with: the view is restored afterwards, so no test depends on
    whether this one ran first."""
    seq = player.make_sequence(heldout_positions(), name="held")
    view = (player.center, player.radius, player.camera_azimuth, player.camera_elevation)
    try:
        res = player.play(seq, out=tmp_path / "held.mp4", max_frames=4, timings=tmp_path / "t.json", progress=False)
    finally:
        player.center, player.radius, player.camera_azimuth, player.camera_elevation = view
    assert res.frames == 4 and (tmp_path / "held.mp4").stat().st_size > 0
    t = json.loads((tmp_path / "t.json").read_text())
    assert t["clip"] == "held" and set(t["frames_ms"]) >= {"pose", "visibility", "shading", "render"}
    assert all(len(v) == 4 for v in t["frames_ms"].values())


def test_deformable_player_never_imports_torch(deformable_run) -> None:
    code = (f"import sys, numpy as np\nfrom prt_torch.cloth.player import DeformablePlayer\n"
            f"from tests.player.deformable_run import heldout_positions\n"
            f"p = DeformablePlayer({str(deformable_run[0])!r})\n"
            f"s, r = p.compute_positions(heldout_positions()[:2])\nassert np.isfinite(r).all()\n"
            f"p.close()\nassert 'torch' not in sys.modules, 'torch imported'\nprint('ok')")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         cwd=Path(__file__).resolve().parents[2])
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr[-2000:]


class _Cache:
    """A vertex cache stand-in holding one sequence (the reader is prt_torch.cloth.cache's, tested there)."""

    fps = 24.0

    def sequences(self) -> list[str]:
        return ["wind0"]

    def positions(self, name: str) -> np.ndarray:
        return heldout_positions()


@pytest.mark.parametrize("case", ["nan", "vertices", "shape", "body", "sequence", "no_cache"])
def test_bad_input_one_line_errors(player, case: str, monkeypatch: pytest.MonkeyPatch) -> None:
    pos = heldout_positions()[:3].copy()
    with pytest.raises(PrtError) as exc:
        if case == "nan":
            pos[1, 5, 0] = np.nan
            player.compute_positions(pos)
        elif case == "vertices":
            player.compute_positions(pos[:, :-1])
        elif case == "shape":
            player.compute_positions(pos[0])
        elif case == "body":
            player.make_sequence(pos, body=np.zeros((3, 2), np.float32))
        elif case == "sequence":
            monkeypatch.setattr(type(player), "_cache", lambda self: _Cache())
            assert player.sequence("wind0").fps == 24.0 and len(player.sequence("wind0")) == len(heldout_positions())
            player.play("no_such_sequence", max_frames=1, progress=False)
        else:
            player.play("wind0", max_frames=1, progress=False)
    msg = str(exc.value)
    assert "\n" not in msg
    want = {"nan": "NaN", "vertices": "vertices", "shape": "(T, V, 3)", "body": "no body features",
            "sequence": "unknown sequence 'no_such_sequence'", "no_cache": "vertex cache"}[case]
    assert want in msg


def test_cli_play_sequence(deformable_run, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                           capsys: pytest.CaptureFixture[str]) -> None:
    """`prt play RUN --sequence NAME --out MP4` plays a cached sequence (the cache reader stubbed) and writes the
    video and the timings; --sequence with --clip is a one-line error."""
    from prt_torch.cli import main
    from prt_torch.cloth.player import DeformablePlayer

    monkeypatch.setattr(DeformablePlayer, "_cache", lambda self: _Cache())
    out = tmp_path / "wind.mp4"
    assert main(["play", str(deformable_run[0]), "--sequence", "wind0", "--out", str(out), "--max-frames", "2",
                 "--size", "120x160", "--timings", str(tmp_path / "t.json")]) == 0
    assert out.stat().st_size > 0 and json.loads((tmp_path / "t.json").read_text())["clip"] == "wind0"
    capsys.readouterr()
    assert main(["play", str(deformable_run[0]), "--sequence", "wind0", "--clip", "walk", "--out", str(out)]) != 0
    err = capsys.readouterr().err.strip()
    assert "--sequence" in err and len(err.splitlines()) == 1
