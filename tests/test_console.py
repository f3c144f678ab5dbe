"""Terminal output a newcomer sees: ``prt eval``'s table and the progress bar stay whole at 80 columns and off a
terminal, log lines carry no source location (prt_torch.progress), and a config's run directory does not depend
on the working directory (prt_torch.config)."""

from __future__ import annotations

import io
import math
import re
import subprocess
import sys
import warnings
from pathlib import Path

import pytest
from rich.cells import cell_len

from prt_torch.commands.eval import HEADERS, results_table
from prt_torch.config import PROJECT_MARKERS, load_config, project_root
from prt_torch.errors import PrtWarning
from prt_torch.progress import NON_TTY_WIDTH, PLAIN_SECONDS, PLAIN_STEPS, make_console, progress_bar

REPO = Path(__file__).resolve().parents[1]
SOURCE_LOCATION = re.compile(r"\b\w+\.py:\d+\b")


def _results(frames: int) -> tuple[dict, dict[str, float]]:
    """An evaluation's results (the shape ``results_table`` reads) with distinct values per cell, and the
    values by name."""
    vals = {"vis": 0.012345, "jit": 0.004567, "ld": 41.2349, "ll": 39.8712, "pd": 37.1051, "pl": 36.5449,
            "rmse": 0.043219}
    sh = {"lambert": {"exact": {"psnr_image": vals["ld"]}, "lobes": {"psnr_image": vals["ll"]}},
          "phong": {"exact": {"psnr_image": vals["pd"]},
                    "lobes": {"psnr_image": vals["pl"], "radiance_rel_rmse": vals["rmse"]}}}
    models = {k: {s: {"shading": {"sky": sh}, "frames": frames, "vis_rel_err": vals["vis"], "jitter": vals["jit"]}
                  for s in ("train", "heldout")} for k in ("linear", "quadratic", "mlp")}
    r = {"frames": {"heldout": frames, "train": 48}, "train_subsampled": True, "player_light": "sky",
         "image_frames": {"heldout": 6, "train": 3}, "models": models}
    return r, vals


def _render(renderable: object, width: int | None = 80) -> str:
    buf = io.StringIO()
    make_console(file=buf, width=width).print(renderable)
    return buf.getvalue()


@pytest.mark.parametrize("width", [80, None])
def test_eval_table_keeps_whole_headers_and_numbers(width: int | None, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("COLUMNS", raising=False)
    r, v = _results(frames=123456)
    out = _render(results_table(r, "runs/builtin"), width)
    lines = out.splitlines()
    rule = next(i for i, line in enumerate(lines) if "───" in line)
    header_words = {w for h in HEADERS for w in h.split()}
    head = [line for line in lines[:rule] if line.split() and set(line.split()) <= header_words]
    title = " ".join(line.strip() for line in lines[:rule] if line not in head and line.strip())
    assert title.startswith("prt eval runs/builtin (heldout: 123456 frames") and title.endswith("lobes lighting")
    if width is None:  # off a terminal the title is one line, unwrapped
        assert lines[0].strip() == title
    assert max(cell_len(line) for line in head + lines[rule:]) <= (width or NON_TTY_WIDTH)
    assert "…" not in out and "..." not in out
    rows = [line.split() for line in lines if line.split()[:1] in (["linear"], ["quadratic"], ["mlp"])]
    assert len(rows) == 6
    # each row is exactly its 10 cells, each number whole: equal to the input within its printed rounding
    for row in rows:
        assert len(row) == len(HEADERS) and row[1] in ("train", "heldout") and row[2] == "123456"
        for tok, x, digits in zip(row[3:], ("vis", "jit", "ld", "ll", "pd", "pl", "rmse"), (4, 4, 2, 2, 2, 2, 4),
                                  strict=True):
            assert abs(float(tok) - v[x]) <= 0.5 * 10**-digits + 1e-12, (tok, x)
    # the header lines (between the title and the rule) hold every header word whole
    assert {w for line in head for w in line.split()} == header_words


def _bar(con: object, fields: tuple[str, ...] = ("frames", "{task.fields[rate]}")) -> object:
    return progress_bar("bake ({task.fields[backend]})", fields, remaining=True, console=con)


@pytest.mark.parametrize("rate, bar, times", [("12.3 frames/s 4.5 Mrays/s", True, True),
                                              ("12.34 frames/s  56.78 Mrays/s", False, True),
                                              ("12.34 frames/s  56.78 Mrays/s (64 workers)", False, False)])
def test_progress_row_at_80_columns_keeps_the_counts(rate: str, bar: bool, times: bool) -> None:
    """On an 80-column terminal the bar shrinks or goes, then the times, so that counts and fields stay whole."""
    con = make_console(file=io.StringIO(), width=80, force_terminal=True)
    p = _bar(con)
    p.add_task("bake", total=1200, completed=445, backend="embree", rate=rate)
    line = _render(p.make_tasks_table(p.tasks)).rstrip("\n")
    assert "\n" not in line and cell_len(line) <= 80 and "…" not in line
    assert "445/1200" in line and rate in line and "bake (embree)" in line
    assert bool(re.search(r"\d:\d\d:\d\d -:--:--$", line)) == times  # elapsed and remaining, whole
    assert ("━" in line) == bar
    # a wide terminal shows the bar whatever the fields
    wide = make_console(file=io.StringIO(), width=160, force_terminal=True)
    q = _bar(wide)
    q.add_task("bake", total=1200, completed=445, backend="embree", rate=rate)
    assert "━" in _render(q.make_tasks_table(q.tasks), 160)


@pytest.mark.parametrize("total", [445, 7, 1000])
def test_progress_off_a_terminal_prints_one_row_per_step(total: int) -> None:
    buf = io.StringIO()
    con = make_console(file=buf)
    assert not con.is_terminal
    with progress_bar(fields=("{task.fields[fps]:.1f} frames/s",), console=con) as p:
        t = p.add_task("play walk", total=total, fps=0.0)
        for _ in range(total):
            p.update(t, advance=1, fps=30.0)
    rows = buf.getvalue().splitlines()
    counts = [int(m.group(1)) for row in rows if (m := re.search(rf"(\d+)/{total}\b", row))]
    assert len(counts) == len(rows)
    # the row of step k is printed at the first count with floor(PLAIN_STEPS * n / total) >= k
    # (several steps may fall on one count: one row for it)
    expected = sorted({math.ceil(k * total / PLAIN_STEPS) for k in range(PLAIN_STEPS + 1)})
    assert counts == expected
    assert all("play walk" in row and "frames/s" in row and "━" not in row for row in rows)


def test_progress_without_total_prints_new_descriptions_at_most_every_interval() -> None:
    buf, clock = io.StringIO(), [0.0]
    with progress_bar(counted=False, spinner=True, console=make_console(file=buf), transient=True,
                      get_time=lambda: clock[0]) as p:
        t = p.add_task("mlp iter 0", total=None)
        for it in range(1, 100):  # one new description per 0.5 s: rows at 0, 10, 20, ... s
            clock[0] = 0.5 * it
            p.update(t, description=f"mlp iter {it}")
        p.update(t, description=f"mlp iter {it}")
    rows = [row.split()[:3] for row in buf.getvalue().splitlines()]
    step = int(PLAIN_SECONDS / 0.5)
    assert rows == [["mlp", "iter", str(i)] for i in range(0, 100, step)]


def test_log_lines_carry_no_source_location() -> None:
    from rich.console import Console

    plain = io.StringIO()
    Console(file=plain, width=100).log("a note")  # rich's default, the control: it names this file
    assert SOURCE_LOCATION.search(plain.getvalue())
    buf = io.StringIO()
    con = make_console(file=buf, width=100)
    con.log("a note")
    with progress_bar(console=con) as p:
        p.console.log("from inside a bar")
    out = buf.getvalue()
    assert "a note" in out and "from inside a bar" in out
    assert not SOURCE_LOCATION.search(out), out


def test_width_off_a_terminal(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("COLUMNS", raising=False)
    assert make_console(file=io.StringIO()).width == NON_TTY_WIDTH
    buf = io.StringIO()
    line = "baked 25 frames in 1.5 s -> " + "/very/long" * 20 + "/dataset.zarr"
    make_console(file=buf).print(line)
    assert buf.getvalue() == line + "\n"  # not wrapped at the layout width: the path stays whole
    assert make_console(file=io.StringIO(), width=72).width == 72
    monkeypatch.setenv("COLUMNS", "90")
    assert make_console(file=io.StringIO()).width == 90


# -- where a config's run directory is ---------------------------------------------------------------------------

def _config(folder: Path, name: str, run_dir: str | None = None) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    p = folder / f"{name}.yaml"
    p.write_text(f"name: {name}\n" + (f"run_dir: {run_dir}\n" if run_dir else "") + "character: {}\n")
    return p


def test_run_dir_is_read_against_the_config_folder(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cfg_path = _config(tmp_path / "proj" / "configs", "x", run_dir="../out/x")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    for cwd in (elsewhere, tmp_path / "proj", tmp_path / "proj" / "configs"):
        monkeypatch.chdir(cwd)
        assert load_config(cfg_path).out_dir == tmp_path / "proj" / "out" / "x"
    monkeypatch.chdir(elsewhere)  # a relative path to the config works the same
    rel = Path("..") / "proj" / "configs" / "x.yaml"
    assert load_config(rel).out_dir == tmp_path / "proj" / "out" / "x"
    # --run-dir is a command-line path: the working directory's
    assert load_config(rel, run_dir="mine").out_dir == Path("mine")


def test_default_run_dir_is_the_projects(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    proj = tmp_path / "proj"
    cfg_path = _config(proj / "configs" / "deep", "y")
    assert project_root(cfg_path.parent) == cfg_path.parent  # no marker at or above it
    monkeypatch.chdir(tmp_path)
    assert load_config(cfg_path).out_dir == proj / "configs" / "deep" / "runs" / "y"
    (proj / PROJECT_MARKERS[0]).write_text("")
    for cwd in (tmp_path, proj / "configs"):
        monkeypatch.chdir(cwd)
        assert load_config(cfg_path).out_dir == proj / "runs" / "y"
    # the shipped configs: the checkout's runs/, from anywhere
    monkeypatch.chdir(tmp_path)
    assert load_config(REPO / "configs" / "builtin.yaml").out_dir == REPO / "runs" / "builtin"


def test_a_run_left_under_the_working_directory_is_named(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cfg_path = _config(tmp_path / "cfgs", "z")
    cwd = tmp_path / "work"
    (cwd / "runs" / "z").mkdir(parents=True)
    monkeypatch.chdir(cwd)
    with pytest.warns(PrtWarning) as rec:
        cfg = load_config(cfg_path)
    msg = str(rec[0].message)
    assert len(rec) == 1 and "\n" not in msg
    assert str(Path("runs") / "z") in msg and str(cfg.out_dir) in msg and "--run-dir runs/z" in msg
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_config(cfg_path, run_dir="runs/z")  # the user chose it: no warning
        cfg.out_dir.mkdir(parents=True)
        load_config(cfg_path)  # the config's own run exists: no warning


def test_cli_from_another_folder_names_the_config_relative_run(tmp_path: Path) -> None:
    """``prt eval CONFIG`` from another folder looks for the run next to the config (and says what it left)."""
    cfg_path = _config(tmp_path / "cfgs", "w", run_dir="runs/w")
    cwd = tmp_path / "work"
    (cwd / "runs" / "w").mkdir(parents=True)
    r = subprocess.run([sys.executable, "-m", "prt_torch", "eval", str(cfg_path)], capture_output=True, text=True,
                       cwd=cwd)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert lines[0].startswith("warning: runs/w (under the working directory)")
    assert lines[-1] == f"error: run directory not found: {tmp_path / 'cfgs' / 'runs' / 'w'}"
