"""``prt bench play --json`` on the tiny run: the issue's keys, and the roofline arithmetic re-derived from the
printed bytes, FLOPs and machine rates (no timing is asserted: benchmarks are never timed tests)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from prt_torch.cli import main


def test_bench_play_json_roofline(tiny_run: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["bench", "play", str(tiny_run), "--frames", "5", "--repeats", "1", "--warmup", "1",
               "--raytrace-frames", "1", "--rays", "16", "--crowd", "1,3", "--batch", "3", "--precisions",
               "fp32,int8", "--json"])
    assert rc == 0
    d = json.loads(capsys.readouterr().out)
    for key in ("fps", "roofline_fraction", "steps", "batched_character_fps", "speedup_vs_raytrace", "bytes_model"):
        assert key in d
    bw, gemm = d["machine"]["copy_bandwidth_gb_s"] * 1e9, d["machine"]["gemm_gflop_s"] * 1e9
    assert d["path"] == "compiled"  # the player's default on the CPU: the frame figures are its own
    for name in ("posing", "visibility", "shading", "fused", "posing_compiled", "compiled"):
        s = d["steps"][name]
        want = max(s["bytes"] / bw, s["flops"] / gemm) * 1e3
        assert s["bound_ms"] == pytest.approx(want, rel=1e-9) and s["ms"] > 0
        assert s["bound_by"] == ("memory" if s["bytes"] / bw >= s["flops"] / gemm else "compute")
    f = d["steps"]["frame"]
    assert f["bound_ms"] == pytest.approx(d["steps"]["posing_compiled"]["bound_ms"]
                                          + d["steps"]["compiled"]["bound_ms"])
    ff = d["steps"]["frame_fused"]  # the numpy posing + fused.onnx frame, side by side
    assert ff["bound_ms"] == pytest.approx(d["steps"]["posing"]["bound_ms"] + d["steps"]["fused"]["bound_ms"])
    assert d["roofline_fraction"] == pytest.approx(f["bound_ms"] / f["ms"])
    assert d["fps"] == pytest.approx(1e3 / f["ms"])
    # the model's bytes: the int8 bases are smaller than float32's, and the shipped (int8) graph's match
    assert d["precisions"]["int8"]["bytes_model"] < 0.6 * d["precisions"]["fp32"]["bytes_model"]
    assert d["precision"] == "int8" and d["vertex_order"] == "cluster"
    assert set(d["crowd"]) == {"1", "3"} and d["batched_character_fps"] == d["crowd"]["3"]["character_fps"]
    # a crowd's bound: weights once, per-character work N times (no more than N single frames, no less than one)
    assert d["crowd"]["1"]["bound_ms"] < d["crowd"]["3"]["bound_ms"] <= 3 * d["crowd"]["1"]["bound_ms"] * (1 + 1e-9)
    assert d["crowd"]["1"]["bound_ms"] == pytest.approx(f["bound_ms"])
    # peak lights on vs off, side by side (the tiny run's sky has one peak, its sun)
    pk = d["peaks"]
    assert pk["n_peaks"] == 1 and pk["fps_on"] == pytest.approx(1e3 / pk["frame_ms_on"])
    assert pk["ratio"] == pytest.approx(pk["frame_ms_off"] / pk["frame_ms_on"])
    assert pk["peak_visibility_ms"] > 0 and pk["peak_shading_ms"] > 0 and pk["frame_ms_on_numba_threads"] > 0
