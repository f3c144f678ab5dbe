"""Run configuration: one YAML file per character/run, validated with pydantic.

A config has sections owned by the stage that reads them::

    name: builtin                 # run name; artifacts go to runs/<name>/ of the project unless run_dir is set
    run_dir: ../runs/x            # optional; a relative path is read against the config file's folder
    character: {...}              # prt_torch.rig.config.CharacterConfig
    bake: {...}                   # prt_torch.bake.config.BakeConfig
    train: {...}                  # prt_torch.fit.config.TrainConfig
    scene: {...}                  # prt_torch.scene.config.SceneConfig (optional: ground, characters)
    cloth: {...}                  # prt_torch.cloth.config.ClothConfig (optional: a simulated deformable run;
                                  # then ``character`` may be omitted: the flag has no body, the cape's is it)

Unknown keys anywhere are errors (``extra="forbid"``); :func:`load_config` turns any validation
problem into a one-line :class:`prt_torch.PrtError` naming the key.

Where paths point (one rule, :meth:`RunConfig.resolve`; the working directory never matters): every relative
path in a config file (``character.source``, motions, ``train.dataset``, ``run_dir``) is read against the config
file's folder. Without ``run_dir`` the run directory is ``runs/<name>`` in the config's project, the nearest
folder at or above the config's that holds a :data:`PROJECT_MARKERS` entry (else the config's folder): so
``configs/builtin.yaml`` of a checkout always means ``<checkout>/runs/builtin``. A command line's ``--run-dir``
is a command-line path (read against the working directory). :func:`load_config` warns (one line) when the run
directory the working directory used to give (``./runs/<name>``, ``./<run_dir>``) exists and the config's
does not, so that no run is silently left behind.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from prt_torch import limits as L
from prt_torch.bake.config import BakeConfig
from prt_torch.cloth.config import ClothConfig
from prt_torch.errors import PrtError, warn
from prt_torch.fit.config import TrainConfig
from prt_torch.rig.config import CharacterConfig
from prt_torch.scene.config import SceneConfig

#: a folder holding one of these is a project root: a config's default run directory is ``runs/<name>`` there
PROJECT_MARKERS = ("pyproject.toml", ".git")


def project_root(folder: Path) -> Path:
    """The nearest folder at or above ``folder`` (absolute) that holds a :data:`PROJECT_MARKERS` entry, else
    ``folder`` itself."""
    for f in (folder, *folder.parents):
        if any((f / m).exists() for m in PROJECT_MARKERS):
            return f
    return folder


class RunConfig(BaseModel):
    """The whole job: which character, how to bake it, how to fit it, where to write.

    ``name`` is a directory name (letters, digits, ``_ . -``, not only dots, at most
    :data:`~prt_torch.limits.MAX_NAME_LENGTH` characters); ``run_dir`` must not name an existing
    file. For the built-in character the memory of one bake task is estimated from ``density`` and
    checked against :data:`~prt_torch.limits.MAX_TASK_BYTES`.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    name: str = Field(pattern=r"^[A-Za-z0-9_.-]+$", max_length=L.MAX_NAME_LENGTH)
    run_dir: Path | None = None
    character: CharacterConfig
    bake: BakeConfig = Field(default_factory=BakeConfig)
    train: TrainConfig = Field(default_factory=TrainConfig)
    scene: SceneConfig | None = None  # ground plane and characters (prt_torch.scene.config); None: no scene
    #: a deformable run (prt_torch.cloth.config, issue 11): positions from the simulated vertex cache, not skinning
    cloth: ClothConfig | None = None

    #: directory of the config file, used to resolve relative paths inside it
    base_dir: Path | None = Field(default=None, exclude=True)

    @field_validator("name")
    @classmethod
    def _name(cls, v: str) -> str:
        if set(v) <= {"."}:
            raise ValueError(f"{v!r} is not a usable directory name")
        return v

    @field_validator("run_dir", mode="before")
    @classmethod
    def _run_dir_text(cls, v: Any) -> Any:
        if isinstance(v, str) and (not v.strip() or "\x00" in v or len(v) > L.MAX_STRING_LENGTH):
            raise ValueError("expected a directory path (non-empty, no NUL, at most "
                             f"{L.MAX_STRING_LENGTH} characters)")
        return v

    @field_validator("run_dir")
    @classmethod
    def _run_dir(cls, v: Path | None) -> Path | None:
        if v is not None and Path(os.path.expanduser(v)).is_absolute():  # a relative one: config_from_dict
            check_run_dir(os.path.expanduser(v))
        return v

    @model_validator(mode="before")
    @classmethod
    def _cloth_character(cls, data: Any) -> Any:
        """A cloth run needs no ``character:`` section (the flag has no body): it defaults to the built-in one."""
        if isinstance(data, dict) and data.get("cloth") is not None and "character" not in data:
            return {**data, "character": {}}
        return data

    @model_validator(mode="after")
    def _bake_memory(self) -> RunConfig:
        # the subject's vertices: the built-in body (skinned runs and the cape) + the cloth (cloth runs); a glTF
        # body's count is known only when it is loaded (checked again by the bake with the real count)
        scene = self.cloth.scene if self.cloth is not None else None
        body = self.character.source == "builtin" and scene != "flag"
        cloth = self.cloth.rows * self.cloth.cols if self.cloth is not None else 0
        if body or cloth:
            b = self.bake
            vertices = (int(L.BUILTIN_VERTICES_PER_DENSITY * self.character.density) if body else 0) + cloth + 1
            try:
                L.check_bake_task_memory(b.frames_per_task, vertices, b.order,
                                         b.transfer_order if b.transfer else None)
            except PrtError as exc:  # "bake.frames_per_task: ...": the formatter takes the key from it
                raise ValueError(str(exc)) from None
        return self

    def resolve(self, p: str | Path) -> Path:
        """Resolve a path from the config relative to the config file's directory."""
        p = Path(os.path.expanduser(p))  # an unknown ~user stays as written
        if p.is_absolute() or self.base_dir is None:
            return p
        return (self.base_dir / p).resolve()

    @property
    def out_dir(self) -> Path:
        """The run directory: ``run_dir`` when set (:func:`load_config` has read a relative one against the config
        file's folder), else ``runs/<name>`` in the config's :func:`project_root` (in the working directory for a
        config that is not from a file)."""
        if self.run_dir is not None:
            return self.run_dir
        if self.base_dir is None:
            return Path("runs") / self.name
        return project_root(self.base_dir) / "runs" / self.name


def check_run_dir(path: str | os.PathLike[str], what: str = "run_dir") -> Path:
    """``path`` as a :class:`Path` if it can be a run directory (missing, or an existing directory).

    Raises :class:`ValueError` (a :class:`PrtError`) naming ``what`` when it is an existing file or below one.
    """
    p = Path(path)
    try:
        for q in (p, *p.parents):
            if q.exists() and not q.is_dir():
                raise PrtError(f"{what} {str(p)[:200]!r}: {str(q)[:200]!r} exists and is not a directory")
    except (OSError, ValueError) as exc:
        if isinstance(exc, PrtError):
            raise
        raise PrtError(f"{what} {str(p)[:200]!r}: not a usable path ({type(exc).__name__})") from None
    return p


def _one_line(text: str, limit: int = 300) -> str:
    """``text`` with control characters escaped, cut to ``limit`` characters: safe for a one-line message."""
    out = "".join(c if c.isprintable() else repr(c)[1:-1] for c in str(text))
    return out if len(out) <= limit else out[: limit - 3] + "..."


def validation_message(exc: ValidationError, source: str) -> str:
    """The one-line message of a config validation error: ``<source>: unknown config key 'a.b'``, ``missing config
    key``, or ``bad value for 'a.b': <why>`` (the first error only)."""
    err = exc.errors()[0]
    loc = _one_line(".".join(str(p) for p in err["loc"]), 120) or "<root>"
    if err["type"] == "extra_forbidden":
        return f"{source}: unknown config key '{loc}'"
    if err["type"] == "missing":
        return f"{source}: missing config key '{loc}'"
    msg = err["msg"].removeprefix("Value error, ")
    m = re.match(r"^([A-Za-z_][A-Za-z0-9_.]*): (.*)$", msg) if not err["loc"] else None
    if m is not None:  # a model-level check that names its key first
        loc, msg = m.group(1), m.group(2)
    return _one_line(f"{source}: bad value for '{loc}': {msg}", 600)


def config_from_dict(data: dict[str, Any], source: str = "config", base_dir: Path | None = None) -> RunConfig:
    """Validate a plain dict as a :class:`RunConfig` (one-line :class:`PrtError` on failure)."""
    if not isinstance(data, dict):
        raise PrtError(f"{source}: expected a mapping at the top level, got {type(data).__name__}")
    try:
        cfg = RunConfig.model_validate(data)
    except ValidationError as exc:
        raise PrtError(validation_message(exc, source)) from None
    except RecursionError:
        raise PrtError(f"{source}: config nested too deeply (at most {L.MAX_CONFIG_DEPTH} levels)") from None
    cfg.base_dir = base_dir
    if cfg.run_dir is not None:
        cfg.run_dir = cfg.resolve(cfg.run_dir)  # ~ expanded; a relative one against the config's folder
        try:
            check_run_dir(cfg.run_dir)
        except PrtError as exc:
            raise PrtError(_one_line(f"{source}: bad value for 'run_dir': {exc}", 600)) from None
    return cfg


class _BoundedLoader(yaml.SafeLoader):
    """PyYAML's safe loader with bounded nesting depth and node count (aliases expanded).

    The composer is recursive (a deeply nested document is a ``RecursionError`` deep inside PyYAML);
    this one refuses documents nested more than :data:`~prt_torch.limits.MAX_CONFIG_DEPTH` levels or with
    more than :data:`~prt_torch.limits.MAX_CONFIG_NODES` nodes before they get there.
    """

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._depth = 0
        self._sizes: dict[int, int] = {}

    def compose_node(self, parent: Any, index: Any) -> Any:
        self._depth += 1
        try:
            if self._depth > L.MAX_CONFIG_DEPTH:
                mark = self.peek_event().start_mark
                raise PrtError(f"nested deeper than {L.MAX_CONFIG_DEPTH} levels at line {mark.line + 1}")
            node = super().compose_node(parent, index)
        finally:
            self._depth -= 1
        if id(node) not in self._sizes:
            if isinstance(node, yaml.SequenceNode):
                children = list(node.value)
            elif isinstance(node, yaml.MappingNode):
                children = [n for kv in node.value for n in kv]
            else:
                children = []
            self._sizes[id(node)] = 1 + sum(self._sizes.get(id(c), 1) for c in children)
        if self._sizes[id(node)] > L.MAX_CONFIG_NODES:
            raise PrtError(f"more than {L.MAX_CONFIG_NODES:,} values (aliases expanded) near line "
                           f"{node.start_mark.line + 1}")
        return node


def _yaml_problem(exc: yaml.YAMLError) -> str:
    """One line from a PyYAML error: its problem and where."""
    problem = getattr(exc, "problem", None) or getattr(exc, "context", None) or str(exc).split("\n")[0]
    mark = getattr(exc, "problem_mark", None) or getattr(exc, "context_mark", None)
    where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
    return _one_line(f"{problem}{where}", 200)


def parse_yaml(text: str, source: str = "config") -> Any:
    """Parse one YAML document with :class:`_BoundedLoader`; every failure is a one-line :class:`PrtError`."""
    loader = None
    try:
        loader = _BoundedLoader(text)  # the reader refuses control characters here
        return loader.get_single_data()
    except PrtError as exc:
        raise PrtError(f"{source}: not a usable config ({exc})") from None
    except yaml.YAMLError as exc:
        raise PrtError(f"{source}: not valid YAML ({_yaml_problem(exc)})") from None
    except RecursionError:
        raise PrtError(f"{source}: not a usable config (nested too deeply)") from None
    except (ValueError, TypeError, OverflowError) as exc:  # e.g. a timestamp out of range in a constructor
        raise PrtError(f"{source}: not valid YAML ({_one_line(str(exc), 200)})") from None
    finally:
        if loader is not None:
            loader.dispose()


def load_config(path: str | Path, run_dir: str | Path | None = None) -> RunConfig:
    """Read and validate a YAML run config (UTF-8, at most :data:`~prt_torch.limits.MAX_CONFIG_BYTES`); its
    relative paths are read against its folder (module docstring). ``run_dir``: a command line's ``--run-dir``
    (read against the working directory), which replaces the config's."""
    path = Path(path)
    try:
        if not path.is_file():
            raise PrtError(f"config file not found: {path}")
        size = path.stat().st_size
        if size > L.MAX_CONFIG_BYTES:
            raise PrtError(f"{path}: config file of {L.human_bytes(size)} is over the "
                           f"{L.human_bytes(L.MAX_CONFIG_BYTES)} bound")
        raw = path.read_bytes()[: L.MAX_CONFIG_BYTES + 1]
    except PrtError:
        raise
    except OSError as exc:
        raise PrtError(f"{path}: cannot read the config ({exc.strerror or type(exc).__name__})") from None
    except ValueError:  # a NUL in the path
        raise PrtError(f"config file not found: {_one_line(str(path), 200)}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise PrtError(f"{path}: not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset {exc.start})") from None
    data = parse_yaml(text, source=str(path))
    cfg = config_from_dict(data, source=str(path), base_dir=path.parent.resolve())
    if run_dir is not None:
        cfg.run_dir = Path(run_dir)
    else:
        _warn_left_behind(cfg, data.get("run_dir"))
    return cfg


def _warn_left_behind(cfg: RunConfig, written: Any) -> None:
    """Warn when the run directory the working directory gave before the config-relative rule (``written``, the
    file's ``run_dir``, or ``runs/<name>``) exists and the config's :attr:`RunConfig.out_dir` does not."""
    old = Path(os.path.expanduser(written)) if isinstance(written, str) else Path("runs") / cfg.name
    new = cfg.out_dir
    try:
        if old.is_absolute() or old.resolve() == new.resolve() or not old.is_dir() or new.exists():
            return
    except (OSError, ValueError):  # an unusable path: validation has named it already where it matters
        return
    rule = "read against the config's folder" if written is not None else "runs/<name> of the config's project"
    warn(f"{old} (under the working directory) is not this config's run directory: that is {new} ({rule}); "
         f"move the run there, or pass --run-dir {old} to use it")
