"""``prt eval`` end to end on ``small_run``: JSON schema, report files, bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from prt_torch.cli import main
from prt_torch.rundir import RunDir

KINDS = ("linear", "quadratic", "mlp")


def test_prt_eval_json_and_report(small_run: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["eval", str(small_run), "--frames", "8", "--image-frames", "2", "--lights", "sky", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["frames"] == {"train": 8, "heldout": 8} and out["image_frames"] == {"train": 2, "heldout": 2}
    assert out["brdfs"] == ["lambert", "phong"] and out["paths"] == ["exact", "lobes"]
    assert list(out["lights"]) == ["sky"]
    for kind in (*KINDS, "unshadowed"):
        for split in ("train", "heldout"):
            m = out["models"][kind][split]
            assert m["frames"] == 8
            for key in ("vis_rel_err", "psnr_diffuse", "psnr_glossy", "jitter", "transfer_rel_err", "rmse_glossy"):
                assert np.isfinite(m[key]), (kind, split, key)
            for brdf in ("lambert", "phong"):
                for path in ("exact", "lobes"):
                    s = m["shading"]["sky"][brdf][path]
                    assert set(s) == {"radiance_rel_rmse", "psnr_vertex", "psnr_image"}
                    assert all(np.isfinite(v) for v in s.values()), (kind, split, brdf, path)
            # the flat keys are the player's light, lobes path
            assert m["psnr_diffuse"] == m["shading"]["sky"]["lambert"]["lobes"]["psnr_image"]
            assert m["psnr_glossy"] == m["shading"]["sky"]["phong"]["lobes"]["psnr_image"]
    for kind in KINDS:
        s = out["storage"][kind]
        assert s["bytes"] > 0 and s["ptd"] > 0 and s["psm"] > 0
    # the models shadow: every kind beats no shadowing on the held-out visibility, radiance and image
    ns = out["models"]["unshadowed"]["heldout"]
    for kind in KINDS:
        m = out["models"][kind]["heldout"]
        assert m["vis_rel_err"] < ns["vis_rel_err"]
        assert m["psnr_diffuse"] > ns["psnr_diffuse"]
        assert m["rmse_diffuse"] < ns["rmse_diffuse"]
    # the lobe fit of the sky costs something, but little
    lf = out["lobe_fit"]["heldout"]["sky"]["lambert"]
    assert 0 < lf["radiance_rel_rmse"] < 0.2 and lf["psnr_image"] > 25
    rep = RunDir(small_run).report_dir
    index = (rep / "index.md").read_text()
    for png in ("spectra.png", "error_vs_variance.png", "error_vs_alpha.png", "per_frame_error.png", "frame.png"):
        assert (rep / png).stat().st_size > 1000, png
        assert png in index
    assert "8 frames" in index and "lobes" in index
    assert (rep / "index.html").is_file() and json.loads(RunDir(small_run).report_json.read_text())["models"]


def test_prt_eval_table_says_frames(small_run: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["eval", str(small_run), "--frames", "4", "--image-frames", "0", "--lights", "sky",
                 "--no-report"]) == 0
    err = capsys.readouterr().err
    assert "heldout: 4 frames" in err and "exact" in err and "lobes" in err
    r = json.loads(RunDir(small_run).report_json.read_text())
    assert r["models"]["mlp"]["heldout"]["psnr_diffuse"] is None  # no frame rendered
    assert r["models"]["mlp"]["heldout"]["shading"]["sky"]["phong"]["exact"]["psnr_vertex"] > 0


def test_prt_eval_bad_input(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["eval", str(tmp_path / "missing")]) == 2
    assert "run directory not found" in capsys.readouterr().err
    assert main(["eval", str(tmp_path)]) == 2
    assert "model metadata not found" in capsys.readouterr().err


def _own_run(small_run: Path, small_dataset: Path, dst: Path) -> RunDir:
    """A copy of ``small_run`` holding its own dataset and character (those beside ``small_dataset``)."""
    import shutil

    shutil.copytree(small_run, dst, ignore=shutil.ignore_patterns("report"))
    src, run = RunDir(small_dataset), RunDir(dst)
    shutil.copytree(src.dataset_path, run.dataset_path)
    shutil.copy2(src.character_path, run.character_path)
    return run


EVAL = ["--frames", "4", "--train-frames", "4", "--image-frames", "1", "--lights", "sky", "--no-report"]


def _warnings(err: str) -> list[str]:
    return [ln for ln in err.splitlines() if ln.startswith("warning: ")]


def test_prt_eval_names_the_dataset_recorded_at_training_time(small_run: Path, small_dataset: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    """``small_run`` has no dataset of its own (it was trained on ``small_dataset``, elsewhere): one warning line
    names the dataset read; its character (beside it) renders the images."""
    run = RunDir(small_run)
    recorded = run.model_meta()["dataset"]
    assert not run.dataset_path.exists() and Path(recorded).resolve() == Path(small_dataset).resolve()
    capsys.readouterr()
    assert main(["eval", str(small_run), *EVAL]) == 0
    err = capsys.readouterr().err
    assert _warnings(err) == [f"warning: {run.dataset_path} not found: reading the dataset recorded at training "
                              f"time, {recorded}"], err
    r = json.loads(run.report_json.read_text())
    assert r["dataset"] == recorded and r["image_frames"] == {"train": 1, "heldout": 1}


def test_prt_eval_of_a_run_with_its_own_dataset_says_nothing(small_run: Path, small_dataset: Path, tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    run = _own_run(small_run, small_dataset, tmp_path / "run")
    capsys.readouterr()
    assert main(["eval", str(run.path), *EVAL]) == 0
    assert _warnings(capsys.readouterr().err) == []
    r = json.loads(run.report_json.read_text())
    assert r["dataset"] == str(run.dataset_path) and r["image_frames"] == {"train": 1, "heldout": 1}


@pytest.mark.parametrize("case", ["missing", "other", "scaled"])
def test_prt_eval_refuses_a_character_that_is_not_the_runs(small_run: Path, small_dataset: Path, tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str], case: str) -> None:
    """``character.npz`` deleted, replaced by another character (the built-in one at another density: another
    vertex count) or by the same mesh scaled by 1% (same vertex count, another content hash): one error line, no
    report (these rendered 0 image frames and exited 0)."""
    from prt_torch.rig.builtin import make_character

    run = _own_run(small_run, small_dataset, tmp_path / "run")
    ch = run.character()
    want = ch.content_hash()
    if case == "missing":
        run.character_path.unlink()
    else:
        other = make_character(0.05) if case == "other" else ch.scaled(1.01)
        assert other.content_hash() != want
        other.save(run.character_path)
    capsys.readouterr()
    assert main(["eval", str(run.path), *EVAL]) == 2
    err = capsys.readouterr().err
    if case == "missing":
        assert err == f"error: no character in {run.path} (character.npz missing): run `prt bake CONFIG` first\n"
    else:
        got = run.character().content_hash()
        assert err == (f"error: {run.character_path} (hash {got[:12]}) is not the character this run was made for "
                       f"({want[:12]})\n")
    assert not run.report_dir.exists()


def test_prt_eval_refuses_a_dataset_of_another_character(small_run: Path, synthetic_dataset: Path, tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    """``--dataset`` of another character (the synthetic store: hash ``synthetic``) than the model's."""
    meta = RunDir(small_run).model_meta()
    capsys.readouterr()
    assert main(["eval", str(small_run), "--dataset", str(synthetic_dataset), *EVAL]) == 2
    assert capsys.readouterr().err == (f"error: {synthetic_dataset} was baked from another character (hash synthetic) "
                                       f"than the model of {small_run} ({meta['character_hash'][:12]})\n")
