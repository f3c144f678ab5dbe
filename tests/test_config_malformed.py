"""Malformed run configs, generated: every one is accepted within the bounds of :mod:`prt_torch.limits` or
refused with ONE line naming the key (never a traceback, a RecursionError or an unbounded allocation).

Property tests (hypothesis, derandomized) mutate the shipped ``configs/*.yaml``: wrong types, NaN / inf /
negative / huge numbers, unknown keys, deep nesting, bad encodings and random bytes. Named cases follow.
"""

from __future__ import annotations

import copy
import math
import re
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from prt_torch import limits as L
from prt_torch.config import RunConfig, config_from_dict, load_config
from prt_torch.errors import PrtError

REPO = Path(__file__).resolve().parents[1]
#: the shipped run configs (scene files, which hold only ``scene:``, are checked in tests/scene/test_config.py)
SHIPPED = {p.name: d for p in sorted((REPO / "configs").glob("*.yaml"))
           if set(d := yaml.safe_load(p.read_text())) != {"scene"}}
#: every leaf key of the shipped configs and the schema's other fields, as (section, key) paths
SECTIONS = {"character": RunConfig.model_fields["character"].annotation,
            "bake": RunConfig.model_fields["bake"].annotation, "train": RunConfig.model_fields["train"].annotation}
PATHS: list[tuple[str, ...]] = [("name",), ("run_dir",)] + [
    (sec, key) for sec, model in SECTIONS.items() for key in model.model_fields]  # type: ignore[union-attr]

SETTINGS = settings(max_examples=150, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

#: values of every wrong kind a user (or a typo) can put in a YAML file
BAD_VALUES = st.one_of(
    st.sampled_from([math.nan, math.inf, -math.inf, -1, -1.5, 0, 0.0, 10**30, -(10**30), 1e308, 2**32, 2**63,
                     True, False, None, "", " ", "x", "nan", "1e400", "-1", "tcp://", "../..", ".", "..",
                     "a\nb", "\x00", [], {}, [None], [math.nan], [-1], ["linear", "linear"], ["foo"],
                     {"a": 1}, [[1]]]),
    st.integers(min_value=-(10**20), max_value=10**20),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=20),
    st.lists(st.one_of(st.integers(-5, 10**7), st.floats(), st.text(max_size=5)), max_size=4),
)


def _one_line_naming_a_key(msg: str) -> None:
    assert "\n" not in msg and "\r" not in msg, msg
    assert len(msg) < 1000, msg
    assert re.search(r"(unknown config key|missing config key|bad value for) '[^']+'", msg), msg


def _check_within_bounds(cfg: RunConfig) -> None:
    """What an accepted config promises the stages (the documented bounds)."""
    ch, b, t = cfg.character, cfg.bake, cfg.train

    def floats(model: Any) -> list[float]:
        out = []
        for v in model.model_dump().values():
            out.extend(x for x in (v if isinstance(v, list) else [v]) if isinstance(x, float))
        return out

    assert all(math.isfinite(x) for m in (ch, b, t) for x in floats(m))
    assert 0 < ch.fps <= L.MAX_FPS and L.MIN_DENSITY <= ch.density <= L.MAX_DENSITY
    assert 0 <= ch.random_poses <= L.MAX_RANDOM_POSES
    assert all(0 <= s <= L.MAX_SEED for s in (ch.seed, b.seed, t.seed))
    assert 16 <= b.n_rays <= L.MAX_RAYS and 1 <= b.frames_per_task <= L.MAX_FRAMES_PER_TASK
    assert 0 <= b.workers <= L.MAX_WORKERS
    assert b.scheduler is None or re.match(L.SCHEDULER_PATTERN, b.scheduler)
    assert t.kinds and t.default_kind in t.kinds and len(set(t.kinds)) == len(t.kinds)
    assert all(1 <= n <= L.MAX_NEURONS for n in t.neurons)
    assert all(0 <= a <= L.MAX_ALPHA for a in t.alphas + t.mlp_alphas)
    assert set(cfg.name) - {"."} and len(cfg.name) <= L.MAX_NAME_LENGTH
    assert cfg.run_dir is None or not cfg.run_dir.exists() or cfg.run_dir.is_dir()
    # the subject baked: the built-in body (skinned runs and the cape; the flag has none) + the cloth's rows x cols
    body = ch.source == "builtin" and (cfg.cloth is None or cfg.cloth.scene != "flag")
    cloth = cfg.cloth.rows * cfg.cloth.cols if cfg.cloth is not None else 0
    if body or cloth:
        v = (int(L.BUILTIN_VERTICES_PER_DENSITY * ch.density) if body else 0) + cloth + 1
        assert L.bake_task_bytes(b.frames_per_task, v, b.order, b.transfer_order if b.transfer else None) \
            <= L.MAX_TASK_BYTES


def _validate(data: Any) -> RunConfig | None:
    """``config_from_dict``: the config, or ``None`` after checking the one-line refusal."""
    try:
        cfg = config_from_dict(data, source="c.yaml")
    except PrtError as exc:
        msg = str(exc)
        if isinstance(data, dict):
            _one_line_naming_a_key(msg)
        else:
            assert "\n" not in msg
        return None
    _check_within_bounds(cfg)
    return cfg


# -- generated ----------------------------------------------------------------------------------------------------

@SETTINGS
@given(base=st.sampled_from(sorted(SHIPPED)), path=st.sampled_from(PATHS), value=BAD_VALUES)
def test_one_mutated_value_is_accepted_within_bounds_or_named(base: str, path: tuple[str, ...], value: Any) -> None:
    data = copy.deepcopy(SHIPPED[base])
    node = data
    for k in path[:-1]:
        node = node.setdefault(k, {})
    node[path[-1]] = value
    try:
        cfg = config_from_dict(data, source="c.yaml")
    except PrtError as exc:
        msg = str(exc)
        _one_line_naming_a_key(msg)
        named = re.search(r"'([^']+)'", msg).group(1)  # type: ignore[union-attr]
        # the mutated key, or the key a cross-field check names (default_kind vs kinds, a task's memory)
        assert named.startswith(".".join(path)) or named in ("train.default_kind", "bake.frames_per_task"), msg
        return
    _check_within_bounds(cfg)


@SETTINGS
@given(base=st.sampled_from(sorted(SHIPPED)),
       muts=st.lists(st.tuples(st.sampled_from(PATHS), BAD_VALUES), min_size=1, max_size=4),
       extra=st.one_of(st.none(), st.tuples(st.sampled_from(["", "character", "bake", "train"]),
                                            st.text(min_size=1, max_size=12))))
def test_several_mutations_and_unknown_keys(base: str, muts: list[tuple[tuple[str, ...], Any]],
                                            extra: tuple[str, str] | None) -> None:
    data = copy.deepcopy(SHIPPED[base])
    for path, value in muts:
        node = data
        for k in path[:-1]:
            node = node.setdefault(k, {}) if isinstance(node.get(k, {}), dict) else {}
        node[path[-1]] = value
    if extra is not None:
        sec, key = extra
        target = data if not sec else data.setdefault(sec, {})
        if isinstance(target, dict):
            target[key] = 1
    _validate(data)


def _nested(depth: int, leaf: Any, kind: str) -> Any:
    for _ in range(depth):
        leaf = [leaf] if kind == "list" else {"k": leaf}
    return leaf


@settings(max_examples=60, deadline=None, derandomize=True)
@given(depth=st.integers(1, 3000), kind=st.sampled_from(["list", "dict"]),
       where=st.sampled_from([("character",), ("character", "train_clips"), ("bake",), ("train", "alphas"),
                              ("name",), ("extra",)]))
def test_deep_nesting_in_dicts_is_one_line(depth: int, kind: str, where: tuple[str, ...]) -> None:
    data = copy.deepcopy(SHIPPED["builtin.yaml"])
    node = data
    for k in where[:-1]:
        node = node[k]
    node[where[-1]] = _nested(depth, 1, kind)
    _validate(data)


@settings(max_examples=60, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(depth=st.integers(1, 5000), style=st.sampled_from(["flow_list", "flow_map", "block_map", "block_list"]))
def test_deep_yaml_files_are_one_line(tmp_path: Path, depth: int, style: str) -> None:
    if style == "flow_list":
        body = "character: {source: builtin}\nbake: " + "[" * depth + "1" + "]" * depth + "\n"
    elif style == "flow_map":
        body = "character: " + "{a: " * depth + "1" + "}" * depth + "\n"
    elif style == "block_map":
        body = "character:\n" + "".join(" " * (i + 1) + f"k{i}:\n" for i in range(min(depth, 1200)))
    else:
        body = "character:\n  train_clips:\n" + "".join(" " * (2 + i) + "-\n" for i in range(min(depth, 1200)))
    p = tmp_path / "deep.yaml"
    p.write_text("name: x\n" + body)
    with pytest.raises(PrtError) as info:
        load_config(p)
    assert "\n" not in str(info.value)


@SETTINGS
@given(prefix=st.binary(max_size=40), suffix=st.binary(max_size=40), base=st.sampled_from(sorted(SHIPPED)))
def test_random_bytes_and_encodings(tmp_path: Path, prefix: bytes, suffix: bytes, base: str) -> None:
    p = tmp_path / "bytes.yaml"
    p.write_bytes(prefix + (REPO / "configs" / base).read_bytes() + suffix)
    try:
        cfg = load_config(p)
    except PrtError as exc:
        assert "\n" not in str(exc)
        return
    _check_within_bounds(cfg)


@SETTINGS
@given(text=st.text(max_size=200))
def test_random_yaml_text(tmp_path: Path, text: str) -> None:
    p = tmp_path / "text.yaml"
    p.write_text(text, encoding="utf-8")
    try:
        cfg = load_config(p)
    except PrtError as exc:
        assert "\n" not in str(exc)
        return
    _check_within_bounds(cfg)


# -- named cases --------------------------------------------------------------------------------------------------

@pytest.mark.parametrize(
    "text, match",
    [
        ("character: {fps: .nan}", "bad value for 'character.fps'"),
        ("character: {fps: .inf}", "bad value for 'character.fps'"),
        ("character: {fps: 0}", "bad value for 'character.fps'"),
        ("character: {fps: -30}", "bad value for 'character.fps'"),
        ("character: {fps: 10000000.0}", "bad value for 'character.fps'"),
        ("character: {seed: -1}", "bad value for 'character.seed'"),
        ("character: {}\nbake: {seed: -3}", "bad value for 'bake.seed'"),
        ("character: {}\ntrain: {seed: -3}", "bad value for 'train.seed'"),
        ("character: {density: 1000}", "bad value for 'character.density'"),
        ("character: {random_poses: 100000000}", "bad value for 'character.random_poses'"),
        ("character: {}\nbake: {n_rays: 100000000}", "bad value for 'bake.n_rays'"),
        ("character: {density: 16}\nbake: {frames_per_task: 4000}", "bad value for 'bake.frames_per_task'.*GiB"),
        ("character: {}\nbake: {scheduler: 'localhost:8786'}", "bad value for 'bake.scheduler'"),
        ("character: {}\nbake: {scheduler: 'tcp://host:0'}", "bad value for 'bake.scheduler'"),
        ("character: {}\ntrain: {kinds: [linear], default_kind: mlp}", "bad value for 'train.default_kind'"),
        ("character: {}\ntrain: {kinds: [linear, foo]}", "bad value for 'train.kinds'"),
        ("character: {}\ntrain: {alphas: [.nan]}", "bad value for 'train.alphas.0'"),
        ("character: {train_clips: [{clip: walk, times: '1e308:'}]}", "bad value for 'character.train_clips"),
    ],
)
def test_named_bad_values(tmp_path: Path, text: str, match: str) -> None:
    p = tmp_path / "c.yaml"
    p.write_text("name: x\n" + text + "\n")
    with pytest.raises(PrtError, match=match) as info:
        load_config(p)
    assert "\n" not in str(info.value)


def test_default_kind_follows_kinds_when_not_given() -> None:
    cfg = config_from_dict({"name": "x", "character": {}, "train": {"kinds": ["linear", "quadratic"]}})
    assert cfg.train.default_kind == "linear"


def test_run_dir_naming_an_existing_file(tmp_path: Path) -> None:
    f = tmp_path / "file"
    f.write_text("x")
    for run_dir in (f, f / "below"):
        with pytest.raises(PrtError, match="bad value for 'run_dir'.*not a directory"):
            config_from_dict({"name": "x", "character": {}, "run_dir": str(run_dir)})
    assert config_from_dict({"name": "x", "character": {}, "run_dir": str(tmp_path / "new")}).run_dir


@pytest.mark.parametrize("name", ["..", ".", "a/b", "", "x" * 200])
def test_unusable_names(name: str) -> None:
    with pytest.raises(PrtError, match="bad value for 'name'"):
        config_from_dict({"name": name, "character": {}})


def test_not_utf8(tmp_path: Path) -> None:
    p = tmp_path / "latin1.yaml"
    p.write_bytes("name: caf\u00e9\ncharacter: {}\n".encode("latin-1"))
    with pytest.raises(PrtError, match=r"not UTF-8 text \(byte 0xe9 at offset 9\)"):
        load_config(p)


def test_deep_yaml_is_one_line_not_a_recursion_traceback(tmp_path: Path) -> None:
    p = tmp_path / "deep.yaml"
    p.write_text("name: x\ncharacter: " + "[" * 3000 + "]" * 3000 + "\n")
    with pytest.raises(PrtError, match="nested deeper than 32 levels at line 2"):
        load_config(p)


def test_alias_bomb_is_refused(tmp_path: Path) -> None:
    lines = ["a0: &a0 [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    lines += [f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 10) + "]" for i in range(1, 9)]
    p = tmp_path / "bomb.yaml"
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(PrtError, match="values \\(aliases expanded\\)"):
        load_config(p)


def test_huge_file_is_refused_before_reading(tmp_path: Path) -> None:
    p = tmp_path / "big.yaml"
    p.write_text("name: x\ncharacter: {}\n# " + "x" * (L.MAX_CONFIG_BYTES + 10) + "\n")
    with pytest.raises(PrtError, match="over the 1.0 MiB bound"):
        load_config(p)


def test_config_is_a_directory(tmp_path: Path) -> None:
    with pytest.raises(PrtError, match="config file not found"):
        load_config(tmp_path)
