"""The site format: every array of data.bin read back through the manifest equals the run's own data; motion files
become clips; the site serves on 127.0.0.1 only."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from tests.tolerance import assert_bitwise


def _array(site: Path, m: dict, name: str) -> np.ndarray:
    e = m["data"]["arrays"][name]
    raw = (site / "assets" / m["data"]["file"]).read_bytes()[e["offset"]:e["offset"] + e["bytes"]]
    return np.frombuffer(raw, np.dtype(e["dtype"]).newbyteorder("<")).reshape(e["shape"])


def test_site_arrays_round_trip_and_motion_clip(tiny_run: Path, shared_data: Path, tmp_path: Path) -> None:
    from prt_torch.rundir import RunDir
    from prt_torch.web.serve import HOST, SiteServer
    from prt_torch.web.site import read_manifest, site_local, write_site

    site = tmp_path / "site"
    write_site(tiny_run, site, material_rpo=False, env_presets=False,
               motions=(str(shared_data / "motion" / "01_01.bvh"),))
    m = read_manifest(site)
    data = (site / "assets" / m["data"]["file"]).read_bytes()
    assert hashlib.sha256(data).hexdigest() == m["data"]["sha256"] and len(data) == m["data"]["bytes"]
    model = (site / "assets" / m["model"]["file"]).read_bytes()  # the page checks both against the manifest
    assert model == RunDir(tiny_run).graph_path("visibility").read_bytes()
    assert hashlib.sha256(model).hexdigest() == m["model"]["sha256"] and len(model) == m["model"]["bytes"]
    ch = RunDir(tiny_run).character()
    assert_bitwise(_array(site, m, "rest_vertices"), ch.rest_vertices,
                   why='the site stores the float32 arrays as they are')
    np.testing.assert_array_equal(_array(site, m, "faces"), ch.faces)
    assert_bitwise(_array(site, m, "inverse_bind"), ch.inverse_bind, why="the site stores the arrays as they are")
    clip = m["clips"][1]
    local = _array(site, m, clip["array"])
    want = site_local(ch, clip["name"], np.arange(clip["frames"]))[:, :, :3, :].reshape(clip["frames"], -1, 12)
    assert_bitwise(local, want, why='the site stores the float32 arrays as they are')
    names = [c["name"] for c in m["clips"]]
    assert names[:len(ch.clips)] == list(ch.clips) and names[-1] == "motion:01_01" and m["clips"][-1]["frames"] > 10
    assert [r["name"] for r in m["rpos"]] == sorted(RunDir(tiny_run).export_meta()["rpo_files"])
    assert m["lights"][0]["name"] == "sky" and len(m["lights"][0]["dirs"]) == 3
    assert m["lights"][0]["tonemap"]["exposure"] > 0
    with SiteServer(site) as srv:
        assert srv.url.startswith(f"http://{HOST}:") and HOST == "127.0.0.1"


def test_site_without_npm_packages_is_one_line_error(tiny_run: Path, tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    from prt_torch.errors import PrtError
    from prt_torch.web.site import web_root, write_site

    fake = tmp_path / "web"
    (fake / "src").mkdir(parents=True)
    for p in (web_root() / "src").iterdir():
        (fake / "src" / p.name).write_bytes(p.read_bytes())
    monkeypatch.setenv("PRT_WEB_ROOT", str(fake))
    with pytest.raises(PrtError, match="npm ci"):
        write_site(tiny_run, tmp_path / "site")
    assert not (tmp_path / "site").exists()  # checked before anything is written
