"""``prt bench rpo --json`` on the tiny run: the sweep's figures against what they must be by construction
(closed forms for the bytes, the untruncated operator for the ``after`` rows at ``k >= C``, Eckart-Young between
the orders, Lambert's rank one); no timing is asserted (benchmarks are never timed tests)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from prt_torch.cli import main
from tests.export.pipeline import build_tiny_run


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_tiny_run(tmp_path_factory.getbasetemp())


def test_bench_rpo_json(tiny_run: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["bench", "rpo", str(tiny_run), "--brdfs", "phong,lambert", "--terms", "2,20", "--frames", "1",
               "--reference-rays", "16", "--repeats", "1", "--json"])
    assert rc == 0
    d = json.loads(capsys.readouterr().out)
    c = d["sh_order"] ** 2
    rows = {(r["brdf"], r["factor_order"], r["k"]): r for r in d["rows"]}
    assert set(rows) == {(b, o, k) for b in ("phong", "lambert") for o in ("before", "after") for k in (2, 20)}
    for (b, o, k), r in rows.items():
        assert r["m_bytes"] == k * c * c * 4  # M (k, C, C) float32
        assert r["bytes"] > 4 * (2 * k * c + 3)  # u, w, tint float32 plus the npz headers
        assert r["ms"] > 0 and 0 < r["psnr_db"] < 100 and r["rel_err"] > 0
        assert r["exact"] == (o == "after" and k >= c)
        if r["exact"] or b == "lambert":  # the untruncated operator itself (Lambert: rank one, any k is exact)
            assert r["op_err"] < 1e-6 and r["rel_err_op"] < 1e-5
    for k in (2, 20):  # Eckart-Young: "after" is the optimum in the SH-domain norm
        assert rows[("phong", "after", k)]["op_err"] <= rows[("phong", "before", k)]["op_err"] + 1e-9
    assert rows[("phong", "before", 2)]["op_err"] > rows[("phong", "before", 20)]["op_err"] > 0
    # a truncated RPO's radiance differs from the untruncated operator's; the reference noise row is there
    assert rows[("phong", "after", 2)]["rel_err_op"] > 1e-3
    assert set(d["noise"]) == {"phong", "lambert"} and d["noise"]["phong"]["psnr_db"] > 0


@pytest.mark.parametrize(("args", "message"), [
    (["--terms", "0"], "--terms: each k must be in 1..256"),
    (["--terms", "a,b"], "--terms: expected comma-separated integers"),
    (["--factor-orders", "sideways"], "--factor-orders: unknown 'sideways'"),
    (["--brdfs", "velvet"], "--brdfs: unknown 'velvet'"),
])
def test_bench_rpo_bad_arguments(tmp_path: Path, args: list[str], message: str,
                                 capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["bench", "rpo", str(tmp_path), *args])
    assert rc != 0
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
