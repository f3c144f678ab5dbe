"""Malformed ``prt`` command lines, generated: each ends in exit status 2 and ONE stderr line ``error: ...``,
and writes NOTHING (the working directory, a run directory and the output paths are listed before and after).

``prt_torch.cli.main(argv)`` runs in-process (argparse errors are ``SystemExit(2)``); a few named cases run
``python -m prt_torch`` in a subprocess. Every generated value is outside the documented bounds
(:mod:`prt_torch.limits`), so the command must refuse it before loading or writing anything.
"""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from prt_torch import limits as L
from prt_torch.cli import main

REPO = Path(__file__).resolve().parents[1]
SETTINGS = settings(max_examples=120, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


@pytest.fixture
def work(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A working directory with a config (run_dir inside it), an empty run directory and a plain file."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "run").mkdir()
    (tmp_path / "afile").write_text("x")
    cfg = (REPO / "configs" / "builtin.yaml").read_text() + f"run_dir: {tmp_path / 'out'}\n"
    (tmp_path / "c.yaml").write_text(cfg)
    return tmp_path


def _listing(root: Path) -> list[tuple[str, int]]:
    return sorted((str(p.relative_to(root)), p.stat().st_size if p.is_file() else -1) for p in root.rglob("*"))


def _invoke(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    capsys.readouterr()
    try:
        rc = main(argv)
    except SystemExit as exc:
        rc = exc.code if isinstance(exc.code, int) else 2
    out, err = capsys.readouterr()
    return rc, out, err


def _assert_refused(argv: list[str], root: Path, capsys: pytest.CaptureFixture[str]) -> str:
    before = _listing(root)
    rc, out, err = _invoke(argv, capsys)
    lines = err.splitlines()
    assert rc == 2, (argv, rc, err)
    assert len(lines) == 1 and lines[0].startswith("error: "), (argv, err)
    assert out == "", (argv, out)
    assert _listing(root) == before, argv
    return lines[0]


def _outside(lo: int, hi: int) -> st.SearchStrategy[int]:
    return st.one_of(st.integers(max_value=lo - 1, min_value=lo - 10**12),
                     st.integers(min_value=hi + 1, max_value=hi + 10**12))


def _bad_float(lo: float, hi: float) -> st.SearchStrategy[str]:
    nums = st.floats(allow_nan=True, allow_infinity=True).filter(lambda x: not (math.isfinite(x) and lo < x <= hi))
    return st.one_of(nums.map(repr), st.sampled_from(["nan", "inf", "-inf", "1e7", "0", "-1e-300"]))


#: (argv before the option, option, strategy of bad values as text)
INT_OPTIONS: list[tuple[list[str], str, int, int]] = [
    (["bake", "c.yaml"], "--workers", 1, L.MAX_WORKERS),
    (["eval", "run"], "--frames", 2, L.MAX_FRAMES),
    (["eval", "run"], "--image-frames", 0, L.MAX_FRAMES),
    (["export", "run"], "--terms", 1, L.MAX_TERMS),
    (["export", "run"], "--opset", L.MIN_OPSET, L.MAX_OPSET),
    (["compare", "run"], "--frames", 1, L.MAX_FRAMES),
    (["compare", "run"], "--image-frames", 0, L.MAX_FRAMES),
    (["compare", "run"], "--reference-frames", 0, L.MAX_FRAMES),
    (["compare", "run"], "--reference-rays", 1, L.MAX_RAYS),
    (["compare", "run"], "--threads", 1, L.MAX_THREADS),
    (["play", "run", "--clip", "walk", "--out", "v.mp4"], "--max-frames", 1, L.MAX_FRAMES),
    (["play", "run", "--clip", "walk", "--out", "v.mp4"], "--threads", 1, L.MAX_THREADS),
    (["demo"], "--max-frames", 1, L.MAX_FRAMES),
    (["light", "afile"], "--order", 1, 16),
    (["light", "afile"], "--lobes", 1, 16),
    (["bench", "shade"], "--vertices", 1, L.MAX_VERTICES),
    (["bench", "shade"], "--k", 1, L.MAX_TERMS),
    (["bench", "shade"], "--repeat", 1, L.MAX_REPEATS),
    (["bench", "shade"], "--threads", 1, L.MAX_THREADS),
    (["bench", "bake"], "--rays", 16, L.MAX_RAYS),
    (["bench", "bake"], "--order", 1, 6),
    (["bench", "bake"], "--frames", 1, L.MAX_RANDOM_POSES),
    (["bench", "bake"], "--workers", 0, L.MAX_WORKERS),
    (["bench", "bake"], "--rounds", 1, L.MAX_REPEATS),
    (["bench", "play", "run"], "--frames", 5, L.MAX_FRAMES),
    (["bench", "play", "run"], "--warmup", 1, L.MAX_REPEATS),
    (["bench", "play", "run"], "--batch", 1, L.MAX_BATCH),
    (["bench", "play", "run"], "--threads", 1, L.MAX_THREADS),
    (["bench", "play", "run"], "--rays", 0, L.MAX_RAYS),
    (["bench", "fit"], "--max-iter", 1, L.MAX_ITERATIONS),
]
FLOAT_OPTIONS: list[tuple[list[str], str, float, float]] = [
    (["play", "run", "--clip", "walk", "--out", "v.mp4"], "--fps", 0.0, L.MAX_FPS),
    (["info", "builtin"], "--fps", 0.0, L.MAX_FPS),
    (["bench", "bake"], "--density", L.MIN_DENSITY - 1e-12, L.MAX_DENSITY),
]
BAD_SIZES = st.one_of(
    st.tuples(_outside(1, L.MAX_IMAGE_SIDE), st.integers(-10, 10**5)).map(lambda t: f"{t[0]}x{t[1]}"),
    st.tuples(st.integers(1, 100), _outside(1, L.MAX_IMAGE_SIDE)).map(lambda t: f"{t[0]}x{t[1]}"),
    st.text(max_size=12).filter(lambda s: not re.fullmatch(r"\s*\d+\s*[xX]\s*\d+\s*", s)),
)
SIZE_COMMANDS = [["play", "run", "--clip", "walk", "--out", "v.mp4"], ["demo"]]
NAME_OPTIONS: list[tuple[list[str], str, tuple[str, ...]]] = [
    (["train", "c.yaml"], "--kinds", ("linear", "quadratic", "mlp")),
    (["export", "run"], "--brdfs", ("lambert", "phong", "blinn", "ggx", "ward")),
    (["compare", "run"], "--methods", ("sh_truth", "unshadowed", "learned_linear", "learned_quadratic",
                                       "learned_mlp")),
    (["demo"], "--brdf", ("lambert", "phong", "ggx", "ward")),
]


@SETTINGS
@given(case=st.sampled_from(INT_OPTIONS), data=st.data())
def test_out_of_range_integers(work: Path, capsys: pytest.CaptureFixture[str], case: tuple,
                               data: st.DataObject) -> None:
    head, opt, lo, hi = case
    value = data.draw(_outside(lo, hi))
    msg = _assert_refused(head + [f"{opt}={value}"], work, capsys)
    assert opt in msg or "order" in msg, msg


@SETTINGS
@given(case=st.sampled_from(INT_OPTIONS), text=st.text(min_size=1, max_size=8))
def test_non_integers_are_one_argparse_line(work: Path, capsys: pytest.CaptureFixture[str], case: tuple,
                                            text: str) -> None:
    head, opt, _, _ = case
    try:
        int(text)
        text += "x"  # argparse's int() would accept it
    except ValueError:
        pass
    msg = _assert_refused(head + [f"{opt}={text}"], work, capsys)
    assert msg.startswith("error: prt "), msg


@SETTINGS
@given(case=st.sampled_from(FLOAT_OPTIONS), data=st.data())
def test_bad_floats(work: Path, capsys: pytest.CaptureFixture[str], case: tuple, data: st.DataObject) -> None:
    head, opt, lo, hi = case
    _assert_refused(head + [f"{opt}={data.draw(_bad_float(lo, hi))}"], work, capsys)


@SETTINGS
@given(head=st.sampled_from(SIZE_COMMANDS), size=BAD_SIZES)
def test_bad_sizes(work: Path, capsys: pytest.CaptureFixture[str], head: list[str], size: str) -> None:
    msg = _assert_refused(head + [f"--size={size}"], work, capsys)
    assert "--size" in msg, msg


@SETTINGS
@given(case=st.sampled_from(NAME_OPTIONS), names=st.lists(st.text(max_size=8), max_size=3))
def test_unknown_names(work: Path, capsys: pytest.CaptureFixture[str], case: tuple, names: list[str]) -> None:
    head, opt, allowed = case
    names = [n.replace(",", "") for n in names]
    if names and all(n.strip() in allowed for n in names) and len({n.strip() for n in names}) == len(names):
        names.append(names[0])  # a repeat is refused too
    _assert_refused(head + [f"{opt}={','.join(names)}"], work, capsys)


@SETTINGS
@given(address=st.one_of(st.text(max_size=30), st.integers(-10, 10**6).map(lambda p: f"tcp://127.0.0.1:{p}"),
                         st.sampled_from(["localhost:8786", "tcp://", "tcp://:1", "http://h:1", "tcp://h:99999"])))
def test_bad_scheduler_addresses(work: Path, capsys: pytest.CaptureFixture[str], address: str) -> None:
    m = re.match(L.SCHEDULER_PATTERN, address)
    if m is not None and 1 <= int(m.group(4)) <= 65535:
        address = address + "/x"
    msg = _assert_refused(["bake", "c.yaml", f"--scheduler={address}"], work, capsys)
    assert "--scheduler" in msg


@SETTINGS
@given(option=st.sampled_from(["--timings", "--out", "--png"]),
       where=st.sampled_from(["run", ".", "afile/x", "missing/x", "missing/deeper/x.json", "afile"]))
def test_play_output_paths(work: Path, capsys: pytest.CaptureFixture[str], option: str, where: str) -> None:
    if option == "--png" and where in ("run", "."):
        where = "missing/x"  # an existing directory is a fine PNG directory
    if option != "--png" and where == "afile":
        where = "afile/y"  # an existing file may be overwritten
    argv = ["play", "run", "--clip", "walk", option, where]
    if option != "--out":
        argv += ["--out", "v.mp4"]
    _assert_refused(argv, work, capsys)


@SETTINGS
@given(argv=st.lists(st.text(max_size=10).filter(lambda s: not s.startswith("-")), max_size=4), command=st.sampled_from(
    ["demo", "light", "bake", "train", "eval", "export", "play", "compare", "info", "bench", "bench shade",
     "bench bake", "bench play", "bench fit"]))
def test_unknown_options(work: Path, capsys: pytest.CaptureFixture[str], argv: list[str], command: str) -> None:
    _assert_refused(command.split() + ["--no-such-option"] + argv, work, capsys)


# -- named cases --------------------------------------------------------------------------------------------------

def _prt(*argv: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.run([sys.executable, "-m", "prt_torch", *argv], capture_output=True, text=True, cwd=cwd,
                          env=env, timeout=120)


@pytest.mark.parametrize("argv", [
    ["play"],                                  # missing RUN and --clip
    ["bench"],                                 # missing NAME
    ["bake", "c.yaml", "--workers", "many"],   # not an int
    ["nosuchcommand"],                         # invalid choice
    ["bake", "c.yaml", "--workers", "0"],      # validated before the store is created
    ["bake", "c.yaml", "--scheduler", "localhost"],
    ["play", "run", "--clip", "walk", "--out", "v.mp4", "--timings", "run"],
    ["play", "run", "--clip", "walk", "--out", "v.mp4", "--size", "-480x640"],
    ["train", "c.yaml", "--kinds", "foo"],
])
def test_named_cases_in_a_subprocess(work: Path, argv: list[str]) -> None:
    before = _listing(work)
    r = _prt(*argv, cwd=work)
    assert r.returncode == 2, r.stderr
    assert len(r.stderr.splitlines()) == 1 and r.stderr.startswith("error: "), r.stderr
    assert "usage:" not in r.stderr and "Traceback" not in r.stderr
    assert _listing(work) == before


def test_help_is_unchanged(capsys: pytest.CaptureFixture[str]) -> None:
    rc, out, err = _invoke(["play", "--help"], capsys)
    assert rc == 0 and out.startswith("usage: prt play") and err == ""


def test_workers_zero_writes_nothing(work: Path, capsys: pytest.CaptureFixture[str]) -> None:
    msg = _assert_refused(["bake", "c.yaml", "--workers", "0"], work, capsys)
    assert msg == f"error: --workers must be in 1..{L.MAX_WORKERS}, got 0"
    assert not (work / "out").exists()


def test_config_fps_error_through_the_cli(work: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (work / "bad.yaml").write_text("name: x\ncharacter: {fps: 1e7}\n")
    msg = _assert_refused(["bake", "bad.yaml"], work, capsys)
    assert "bad value for 'character.fps'" in msg


def test_run_dir_naming_a_file(work: Path, capsys: pytest.CaptureFixture[str]) -> None:
    msg = _assert_refused(["bake", "c.yaml", "--run-dir", "afile"], work, capsys)
    assert "--run-dir" in msg and "not a directory" in msg


@pytest.mark.parametrize("where", ["option", "config"])
def test_unreachable_scheduler_writes_nothing(work: Path, capsys: pytest.CaptureFixture[str],
                                              monkeypatch: pytest.MonkeyPatch, where: str) -> None:
    """``--scheduler`` (or ``bake.scheduler``) where no scheduler listens: the bake connects before it creates the
    run directory or the store, so the one error line leaves nothing behind (connect timeout shortened to 2 s)."""
    from prt_torch.bake import runner

    monkeypatch.setattr(runner, "SCHEDULER_TIMEOUT_S", 2.0)
    address = "tcp://127.0.0.1:1"  # a privileged port: nothing listens there
    if where == "option":
        argv = ["bake", "c.yaml", "--scheduler", address]
    else:
        cfg = (work / "c.yaml").read_text()
        (work / "d.yaml").write_text(cfg.replace("bake:\n", f"bake:\n  scheduler: {address}\n"))
        argv = ["bake", "d.yaml"]
    msg = _assert_refused(argv, work, capsys)
    assert msg.startswith(f"error: cannot connect to the Dask scheduler at '{address}' (") and \
        msg.endswith("); nothing written"), msg
    assert not (work / "out").exists()


def test_stray_gltf_vertex_writes_nothing(work: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A glTF character with one vertex at 1e30 baked with exit 0 as an unoccluded speck (``height`` shrank every
    other vertex to a point): now one line at load time, nothing written."""
    from tests.rig.test_gltf import write_rig

    write_rig(work / "stray.glb", stray=1e30)
    (work / "s.yaml").write_text(f"name: s\nrun_dir: {work / 'out'}\ncharacter: {{source: stray.glb, height: 1.8, "
                                 f"train_clips: [lin]}}\nbake: {{n_rays: 16, workers: 1}}\n")
    msg = _assert_refused(["bake", "s.yaml"], work, capsys)
    assert re.fullmatch(r"error: stray\.glb: vertex 4 at \(1e\+30, [^)]*\) has a coordinate beyond 1e\+07 "
                        r"\(limits\.MAX_COORDINATE\)", msg), msg
    assert not (work / "out").exists()


def test_key_without_effect_is_one_warning_line(work: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``character.density`` on a glTF character: the bake runs (exit 0) and says once, on one line, that the key
    is ignored."""
    from tests.rig.test_gltf import write_rig

    write_rig(work / "rig.glb")
    (work / "g.yaml").write_text(f"name: g\nrun_dir: {work / 'out'}\ncharacter: {{source: rig.glb, density: 0.5, "
                                 f"fps: 5, train_clips: [lin]}}\nbake: {{order: 2, n_rays: 16, workers: 1}}\n")
    rc, out, err = _invoke(["bake", "g.yaml", "--no-progress"], capsys)
    assert rc == 0, err
    warned = [ln for ln in err.splitlines() if ln.startswith("warning: ")]
    assert warned == ["warning: character.density has no effect on a glTF character (it sets the built-in "
                      "humanoid's vertex density); ignored"], err
    assert (work / "out" / "dataset.zarr").is_dir()


def test_version_is_the_installed_distributions(capsys: pytest.CaptureFixture[str]) -> None:
    """``prt --version`` prints the version the installed distribution's metadata records (exit 0)."""
    from importlib.metadata import version

    from prt_torch.cli import main

    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.strip() == f"prt {version('prt-torch')}"
