"""``prt bake CONFIG`` and ``prt bench bake`` as a user runs them (subprocesses)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import yaml

from prt_torch.bake.store import open_dataset
from tests.tolerance import assert_bitwise


def prt(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "prt_torch.cli", *args], capture_output=True, text=True, timeout=300)


def test_prt_bake_then_resume(tmp_path: Path) -> None:
    cfg = {"name": "cli", "character": {"source": "builtin", "density": 0.05, "fps": 2.0, "random_poses": 6,
                                        "heldout_clips": ["wave"]},
           "bake": {"order": 2, "n_rays": 32, "frames_per_task": 4}}
    path = tmp_path / "cli.yaml"
    path.write_text(yaml.safe_dump(cfg))
    run_dir = tmp_path / "run"
    out = prt("bake", str(path), "--run-dir", str(run_dir), "--workers", "1", "--json", "--no-progress")
    assert out.returncode == 0, out.stderr
    first = json.loads(out.stdout)
    ds = open_dataset(first["dataset"])
    assert ds.complete and first["frames"] == ds.n_frames and first["skipped"] == 0
    assert first["rays"] == ds.n_frames * ds.n_vertices * 32 and first["frames_per_s"] > 0
    vis = ds.visibility
    again = json.loads(prt("bake", str(path), "--run-dir", str(run_dir), "--json", "--no-progress").stdout)
    assert again["frames"] == 0 and again["skipped"] == ds.n_frames
    assert_bitwise(open_dataset(run_dir).visibility, vis,
                   why='the bake is bit-exact: a resumed bake equals an uninterrupted one')
    missing = prt("bake", str(tmp_path / "nope.yaml"))
    assert missing.returncode == 2 and missing.stderr.startswith("error: config file not found")


def test_prt_bench_bake_json_keys() -> None:
    out = prt("bench", "bake", "--density", "0.05", "--rays", "32", "--frames", "4", "--rounds", "1", "--workers",
              "1", "--json")
    assert out.returncode == 0, out.stderr
    res = json.loads(out.stdout)
    for key in ("rays_per_s", "raw_rays_per_s", "ratio", "frames_per_s"):
        assert res[key] > 0
    assert res["vertices"] > 0 and res["frames"] == 4
