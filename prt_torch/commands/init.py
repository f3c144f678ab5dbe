"""``prt init FILE.glb|.gltf [--motion FILE_OR_DIR ...] [--minutes M] [--out CONFIG]``: a run config for your own
humanoid, ready for ``prt bake CONFIG && prt train CONFIG && prt export RUN && prt compare RUN`` as is.

What it does, in order:

1. **Reads the character** (:func:`prt_torch.rig.gltf.load_gltf`: several meshes, rigid parts on joint nodes and
   un-normalised weights load as one character, each fix-up one ``warning:`` line) and checks that its skeleton is
   a humanoid (:func:`prt_torch.rig.joint_map.find_roles`; the Fox is one ``error:`` line). A file whose rest
   height is not a plausible number of metres (outside ``0.5..3``) gets ``height: 1.8``.
2. **Adds the motions**: each ``--motion`` file (``.bvh``, ``.glb``, ``.gltf``; a directory adds every such file
   in it, sorted) is retargeted onto the character now (:func:`prt_torch.rig.retarget.retarget_file`) so a motion
   that cannot drive it is an error here, not in the bake; what the retargeting detected is printed as warnings.
3. **Proposes the split** (:func:`propose_split`): the character's own clips and the motions are grouped into
   categories (a CMU file ``SS_TT`` by its subject ``SS``; other motions by their directory when they come from
   several, else each file alone; the character's own clips one category). With two categories or more, the
   smallest (fewest seconds) is held out whole - a motion category absent from training; with one category of
   several clips, its shortest clip; with a single clip, its last quarter (a within-clip tail).
4. **Sizes the job** (:func:`choose_budget`) from a short measured probe (:func:`probe`): Embree traces the rest
   pose at two ray counts (bake seconds per frame = ``a + b R``), and a ridge solve of the training matrix's shape
   gives the fit's throughput. The first of :data:`LADDER` (rays per vertex x frame rate, best first) whose
   estimated bake + train time fits ``--minutes`` is taken; when none does, the lowest rung with every clip cut to
   the seconds that fit, and one warning line. A glTF character's vertex count is the file's (density is the
   built-in humanoid's knob only), so rays and frames are what the budget buys. The config's comments carry the
   probe figures and the estimate.

The config is validated (:func:`prt_torch.config.config_from_dict`) before it is written, atomically; an existing
``--out`` is refused unless ``--force``. Paths in it are relative to the config's directory (absolute where the
two share nothing but the root); the run directory is the config's own (:attr:`prt_torch.config.RunConfig.out_dir`),
named in the printed next commands.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from prt_torch.rig.character import Character

HELP = "Write a run config for your own humanoid glTF (+ motions): split, retargeting and a measured time budget."

#: motion file suffixes ``--motion`` takes
MOTION_SUFFIXES = (".bvh", ".glb", ".gltf")
#: (rays per vertex, frames per second), best first: the budget takes the first rung that fits
LADDER: tuple[tuple[int, float], ...] = (
    (512, 30.0), (512, 15.0), (256, 30.0), (256, 15.0), (512, 10.0), (256, 10.0), (128, 15.0), (128, 10.0),
    (128, 6.0), (64, 10.0), (64, 6.0), (64, 3.0), (32, 6.0), (32, 3.0), (16, 3.0))
#: the share of the training frames added as random poses (perturbed training frames)
RANDOM_SHARE = 0.25
#: the held-out tail of a single clip
TAIL_SHARE = 0.25
#: the share of the seconds the held-out category (or clip) should come closest to
HELDOUT_SHARE = 0.2
#: rays per vertex of the probe's two bakes, their frames and frames per task (block)
PROBE_RAYS = (32, 128)
PROBE_FRAMES = 16
PROBE_TASK = 4
#: parallel efficiency of the bake's process pool (one worker per core) on a busy machine, and its start-up
POOL_EFFICIENCY = 0.75
POOL_START_SECONDS = 2.0
#: train constants, measured on this project's 2-core machine with other jobs running (docs/DESIGN.md "prt init"):
#: seconds of the MLP's cross-validated fit per training frame per grid unit, of the quadratic fit per training
#: frame, of the reductions (pose / visibility PCA, clusters) per frame x vertex x coefficient, and the fixed
#: start-up of ``prt train``
MLP_SECONDS = 0.02
QUADRATIC_SECONDS = 0.008
REDUCE_SECONDS = 1e-6
TRAIN_FIXED_SECONDS = 8.0
#: :func:`fit_workload`'s seconds on that machine (the speed reference of the train constants)
REFERENCE_FIT_SECONDS = 0.025
#: frames from which the train section takes the full hyper-parameter grid (:func:`train_grid`)
FULL_GRID_FRAMES = 400
#: plausible rest heights in metres; outside them the config rescales to DEFAULT_HEIGHT
HEIGHT_RANGE = (0.5, 3.0)
DEFAULT_HEIGHT = 1.8


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", metavar="FILE", help="a humanoid .glb/.gltf character")
    parser.add_argument("--motion", action="append", default=[], metavar="FILE_OR_DIR",
                        help="a motion (.bvh, humanoid .glb/.gltf) or a directory of them; repeatable")
    parser.add_argument("--minutes", type=float, default=20.0,
                        help="time for bake + train on this machine, in minutes (default 20)")
    parser.add_argument("--out", default=None, help="the config to write (default: ./<name>.yaml)")
    parser.add_argument("--name", default=None, help="the run name (default: the file's stem)")
    parser.add_argument("--force", action="store_true", help="overwrite an existing --out")
    parser.add_argument("--json", action="store_true", help="print the plan as one JSON object")


@dataclass
class Item:
    """One clip the config can use: the character's own ``clip`` or a motion ``file`` (``name`` its clip name),
    ``seconds`` long, in ``category``."""

    name: str
    seconds: float
    category: str
    file: Path | None = None
    warnings: list[str] = field(default_factory=list)


@dataclass
class Split:
    """``train`` / ``heldout``: config entries (clip names or ``{clip, times, name}`` ranges); ``why``: one line."""

    train: list[Any]
    heldout: list[Any]
    why: str


@dataclass
class Probe:
    """Measured on this machine by :func:`probe`.

    ``bake_fixed`` seconds of a bake's start-up (plan, store, worker pool) and ``a + b R`` wall seconds per frame
    at ``R`` rays per vertex, from two real bakes of ``probe_frames`` frames (:data:`PROBE_RAYS`) through the
    bake's own code, serially in this process (posing, vertex frames, tracing, projection and the store's writes:
    the median block's seconds per frame over :data:`POOL_EFFICIENCY` x the cores the pool will use; the start-up
    plus :data:`POOL_START_SECONDS`);
    ``fit_seconds``: :func:`fit_workload` here, against :data:`REFERENCE_FIT_SECONDS` on the machine the train
    constants were measured on; ``load_seconds``: loading the character and retargeting the motions (each of
    ``prt bake`` and ``prt train`` does it once)."""

    bake_fixed: float
    a: float
    b: float
    fit_seconds: float
    load_seconds: float
    probe_frames: int
    traced: list[tuple[int, float]]

    def bake_seconds(self, frames: int, rays: int) -> float:
        """Estimated wall seconds of ``prt bake`` of ``frames`` frames at ``rays`` rays per vertex."""
        return self.load_seconds + self.bake_fixed + frames * (self.a + self.b * rays)

    def train_seconds(self, train_frames: int, frames: int, vertices: int, coeffs: int, grid: float) -> float:
        """Estimated wall seconds of ``prt train``: ``train_frames`` training frames (``frames`` in all) of
        ``vertices x coeffs`` visibility, ``grid`` MLP grid units (:func:`grid_units`)."""
        speed = self.fit_seconds / REFERENCE_FIT_SECONDS
        work = ((MLP_SECONDS * grid + QUADRATIC_SECONDS) * train_frames
                + REDUCE_SECONDS * frames * vertices * coeffs)
        return self.load_seconds + TRAIN_FIXED_SECONDS + speed * work


@dataclass
class Budget:
    """The chosen ``rays`` and ``fps``, ``cap_seconds`` per clip (``None``: whole clips), the frame counts, the
    estimate in seconds and whether the fits take the full grid (:func:`train_grid`)."""

    rays: int
    fps: float
    cap_seconds: float | None
    frames: int
    random_poses: int
    bake_s: float
    train_s: float
    full_grid: bool = False

    @property
    def total_s(self) -> float:
        return self.bake_s + self.train_s


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from prt_torch.config import config_from_dict, parse_yaml
    from prt_torch.errors import PrtError, warn
    from prt_torch.io import atomic_write_text

    path = Path(args.file)
    if path.suffix.lower() not in (".glb", ".gltf"):
        raise PrtError(f"prt init: {path.name}: expected a .glb/.gltf character")
    if not path.is_file():
        raise PrtError(f"prt init: character file not found: {path}")
    if not (math.isfinite(args.minutes) and 0 < args.minutes <= 24 * 60):
        raise PrtError(f"prt init: --minutes must be in (0, 1440], got {args.minutes}")
    name = args.name or re.sub(r"[^A-Za-z0-9_.-]+", "_", path.stem).strip("._") or "character"
    out = Path(args.out) if args.out is not None else Path(f"{name}.yaml")
    if out.suffix.lower() not in (".yaml", ".yml"):
        raise PrtError(f"prt init: --out {out}: expected a .yaml file")
    if out.exists() and not args.force:
        raise PrtError(f"prt init: {out} exists (--force overwrites it)")
    if out.is_dir():
        raise PrtError(f"prt init: --out {out} is a directory")

    motion_files = expand_motions(args.motion)  # every argument checked before the character loads

    from prt_torch.rig.gltf import load_gltf

    t_load = time.perf_counter()
    character = load_gltf(path, fps=30.0)
    humanoid_roles(character, path.name)
    height = float(np.ptp(character.rest_vertices[:, 2]))
    rescale = not HEIGHT_RANGE[0] <= height <= HEIGHT_RANGE[1]
    if rescale:  # as load_gltf(height=...) does when the config is read
        character = character.scaled(DEFAULT_HEIGHT / height)
    items = [Item(n, clip.duration, f"{path.stem} clips") for n, clip in character.clips.items()]
    items += motion_items(character, motion_files, {i.name for i in items})
    for item in items:
        for w in item.warnings:
            warn(w)
    if not items:
        raise PrtError(f"prt init: {path.name} has no animations; pass --motion FILE_OR_DIR (a .bvh or a humanoid "
                       f".glb/.gltf, or a directory of them)")
    load_seconds = time.perf_counter() - t_load
    _low_poly(path.name, character.num_vertices)
    split = propose_split(items)
    config_dir = out.resolve().parent
    pr = probe(probe_section(path, items, rescale), config_dir, load_seconds)
    budget = choose_budget(items, split, pr, character.num_vertices, args.minutes * 60.0)
    if budget.total_s > args.minutes * 60.0 * 1.05:
        cut = "" if budget.cap_seconds is None else f" with clips cut to {budget.cap_seconds:.2g} s"
        warn(f"{path.name}: even {budget.rays} rays at {budget.fps:g} fps{cut} is estimated at "
             f"{budget.total_s / 60:.1f} min, over --minutes {args.minutes:g}")
    elif budget.cap_seconds is not None:
        warn(f"{path.name}: --minutes {args.minutes:g} fits only {budget.cap_seconds:.2g} s of each clip at "
             f"{budget.rays} rays, {budget.fps:g} fps; the clips are cut")
    data = json.loads(json.dumps(config_data(name, path, out, character, items, split, budget, rescale)))
    cfg = config_from_dict(data, str(out), base_dir=config_dir)  # as prt bake reads it
    run_dir = _shown(cfg.out_dir)
    text = config_text(data, path, items, split, budget, pr, character.num_vertices, height, rescale, args.minutes,
                       run_dir)
    if parse_yaml(text, str(out)) != data:  # the comments and the flow values say what the dict says
        raise PrtError(f"prt init: internal error: the written YAML of {out} does not read back as its values")
    atomic_write_text(out, text)
    summary = {"config": str(out), "run_dir": run_dir, "character": path.name, "vertices": character.num_vertices,
               "joints": character.num_joints, "height": height, "rescaled_to": DEFAULT_HEIGHT if rescale else None,
               "clips": [{"name": i.name, "seconds": round(i.seconds, 3), "category": i.category} for i in items],
               "train_clips": split.train, "heldout_clips": split.heldout, "split": split.why,
               "n_rays": budget.rays, "fps": budget.fps, "cap_seconds": budget.cap_seconds, "frames": budget.frames,
               "random_poses": budget.random_poses,
               "estimate_s": {"bake": round(budget.bake_s, 1), "train": round(budget.train_s, 1),
                              "total": round(budget.total_s, 1)},
               "probe": {"bake_s_per_frame": [[r, round(t, 5)] for r, t in pr.traced],
                         "bake_fixed_s": round(pr.bake_fixed, 3), "fit_s": round(pr.fit_seconds, 5),
                         "load_s": round(pr.load_seconds, 3)}}
    if args.json:
        json.dump(summary, sys.stdout)
        sys.stdout.write("\n")
    else:
        print(f"wrote {out}: {path.name}, {character.num_vertices} vertices, {character.num_joints} joints; "
              f"{budget.rays} rays, {budget.fps:g} fps, {budget.frames} frames; estimated bake + train "
              f"{budget.total_s / 60:.1f} min")
        print(f"split: {split.why}")
        print(f"next: prt bake {out} && prt train {out} && prt export {run_dir} && prt compare {run_dir}")
    return 0


def _low_poly(name: str, vertices: int) -> None:
    """The low-poly advice of ``prt info`` (:func:`prt_torch.rig.lowpoly.low_poly_advice`) as one warning line."""
    from prt_torch.errors import warn
    from prt_torch.rig.lowpoly import low_poly_advice

    advice = low_poly_advice(vertices)
    if advice is not None:
        warn(f"{name}: {advice}")


def probe_section(path: Path, items: list[Item], rescale: bool) -> dict[str, Any]:
    """The probe's ``character`` section: 4 frames of the first clip (a motion retargeted when the file has none)
    and :data:`PROBE_FRAMES` - 4 random poses of them."""
    ch: dict[str, Any] = {"source": str(path.resolve()), "fps": 30.0}
    if rescale:
        ch["height"] = DEFAULT_HEIGHT
    first = items[0]
    if first.file is not None:
        ch["motions"] = [{"file": str(first.file.resolve()), "name": first.name}]
    ch["train_clips"] = [{"clip": first.name, "frames": "0:4"}]
    ch["random_poses"] = PROBE_FRAMES - 4
    return ch


def _shown(p: Path) -> str:
    """``p`` relative to the working directory when it lies below it, else absolute."""
    p = Path(os.path.abspath(p))
    try:
        return p.relative_to(Path.cwd().resolve()).as_posix()
    except ValueError:
        return p.as_posix()


def humanoid_roles(character: Character, what: str) -> Any:
    """:class:`prt_torch.rig.joint_map.SkeletonRoles` of the character's rest skeleton; a skeleton that is not a
    humanoid is one :class:`PrtError` line saying so (and why)."""
    import numpy as np

    from prt_torch.errors import PrtError
    from prt_torch.rig.joint_map import find_roles

    rest = np.linalg.inv(character.inverse_bind)[:, :3, 3]
    try:
        return find_roles(character.joint_names, character.parents, rest, what)
    except PrtError as e:
        raise PrtError(f"prt init needs a humanoid character: {e}") from None


def expand_motions(entries: list[str]) -> list[Path]:
    """``--motion`` arguments -> motion files (a directory: its ``.bvh/.glb/.gltf`` files, sorted); a missing path,
    an empty directory or another suffix is one :class:`PrtError` line."""
    from prt_torch.errors import PrtError

    out: list[Path] = []
    for e in entries:
        p = Path(e)
        if p.is_dir():
            files = sorted(f for f in p.iterdir() if f.is_file() and f.suffix.lower() in MOTION_SUFFIXES)
            if not files:
                raise PrtError(f"prt init: --motion {p}: no .bvh/.glb/.gltf file in the directory")
            out += files
        elif p.is_file():
            if p.suffix.lower() not in MOTION_SUFFIXES:
                raise PrtError(f"prt init: --motion {p}: expected a .bvh/.glb/.gltf file or a directory")
            out.append(p)
        else:
            raise PrtError(f"prt init: --motion {p}: no such file or directory")
    seen: set[Path] = set()
    return [p for p in out if not (p.resolve() in seen or seen.add(p.resolve()))]  # type: ignore[func-returns-value]


def motion_category(path: Path, several_dirs: bool) -> str:
    """A CMU ``SS_TT`` file's subject ``cmu_SS``; else the directory name when motions come from several, else the
    file's stem."""
    m = re.fullmatch(r"0*(\d+)_\d+", path.stem)
    if m is not None:
        return f"cmu_{m.group(1)}"
    return path.parent.name if several_dirs else path.stem


def motion_items(character: Character, files: list[Path], taken: set[str]) -> list[Item]:
    """Retarget every file onto ``character`` (a failure is one :class:`PrtError` line naming the file) -> items
    named after the file stems (made unique against ``taken``)."""
    from prt_torch.errors import PrtError
    from prt_torch.rig.retarget import retarget_file

    several = len({f.resolve().parent for f in files}) > 1
    out: list[Item] = []
    names = set(taken)
    for f in files:
        base = re.sub(r"[^A-Za-z0-9_.-]+", "_", f.stem) or "motion"
        name, k = base, 2
        while name in names:
            name, k = f"{base}_{k}", k + 1
        names.add(name)
        try:
            clip, report = retarget_file(f, character, fps=30.0, name=name)
        except PrtError as e:
            raise PrtError(f"prt init: --motion {f}: {e}") from None
        notes = [w.removeprefix("warning: ") for w in report.warnings]
        out.append(Item(name, clip.duration, motion_category(f, several), f,
                        [w if f.name in w else f"{f.name}: {w}" for w in notes]))
    return out


def propose_split(items: list[Item]) -> Split:
    """The held-out set (see the module docstring): a whole category, a whole clip, or a clip's tail.

    The candidates are the motions' categories when they have two or more (the character's own clips then always
    train), else every category; the one held out is the one whose seconds come closest to :data:`HELDOUT_SHARE`
    of the candidates' total (ties: the first by name). With a single category of several clips the same rule
    picks one clip."""
    cats: dict[str, list[Item]] = {}
    for i in items:
        cats.setdefault(i.category, []).append(i)
    motion_cats = {c for c, its in cats.items() if all(i.file is not None for i in its)}
    candidates = sorted(motion_cats if len(motion_cats) >= 2 else cats)
    if len(candidates) >= 2:
        total = sum(i.seconds for c in candidates for i in cats[c])
        held = min(candidates, key=lambda c: abs(sum(i.seconds for i in cats[c]) - HELDOUT_SHARE * total))
        held_names = [i.name for i in cats[held]]
        return Split([i.name for i in items if i.category != held], held_names,
                     f"held out the whole category {held!r} ({', '.join(held_names)}), absent from training")
    if len(items) >= 2:
        total = sum(i.seconds for i in items)
        held_item = min(sorted(items, key=lambda i: i.name), key=lambda i: abs(i.seconds - HELDOUT_SHARE * total))
        return Split([i.name for i in items if i is not held_item], [held_item.name],
                     f"held out the whole clip {held_item.name!r} (one category: the clip nearest "
                     f"{HELDOUT_SHARE:.0%} of its {total:.1f} s)")
    (only,) = items
    t = round(only.seconds * (1 - TAIL_SHARE), 3)
    return Split([{"clip": only.name, "times": f"0:{t:g}", "name": f"{only.name}_head"}],
                 [{"clip": only.name, "times": f"{t:g}:", "name": f"{only.name}_tail"}],
                 f"held out the last {TAIL_SHARE:.0%} of the only clip {only.name!r} (from {t:g} s)")


def fit_workload(seed: int = 0) -> float:
    """Seconds of a fixed piece of the MLP fit's arithmetic (a one-hidden-layer tanh network's forward and backward
    pass, 30 times over 2048 x 48 inputs -> 16 neurons -> 64 outputs, float64 numpy, one BLAS thread; best of 3):
    this machine's speed on the work ``prt train`` does, under its present load."""
    import numpy as np
    from threadpoolctl import threadpool_limits

    rng = np.random.default_rng(seed)
    x = rng.standard_normal((2048, 48))
    y = rng.standard_normal((2048, 64))
    w1, w2 = rng.standard_normal((48, 16)) * 0.1, rng.standard_normal((16, 64)) * 0.1
    best = math.inf
    with threadpool_limits(limits=1):  # one BLAS thread: a measure of one core, not of the thread pool's luck
        for _ in range(3):
            t0 = time.perf_counter()
            for _ in range(30):
                h = np.tanh(x @ w1)
                r = h @ w2 - y
                g2 = h.T @ r
                g1 = x.T @ ((r @ w2.T) * (1 - h * h))
                w1 -= 1e-6 * g1
                w2 -= 1e-6 * g2
            best = min(best, time.perf_counter() - t0)
    return best


def probe(base: dict[str, Any], config_dir: Path, load_seconds: float) -> Probe:
    """Two real bakes of :data:`PROBE_FRAMES` frames in blocks of :data:`PROBE_TASK` (random poses of the first
    clip, :data:`PROBE_RAYS` rays per vertex) of the ``character`` section ``base`` (paths relative to
    ``config_dir``) into a temporary run directory, removed afterwards, and :func:`fit_workload`."""
    import shutil
    import tempfile

    from prt_torch.bake.runner import run_bake
    from prt_torch.config import config_from_dict

    tmp = Path(tempfile.mkdtemp(prefix="prt-init-probe-"))
    traced: list[tuple[int, float, float]] = []
    par = max(1.0, POOL_EFFICIENCY * _cores())
    try:
        for rays in PROBE_RAYS:
            data = {"name": "probe", "run_dir": str(tmp / f"rays{rays}"), "character": base,
                    "bake": {"order": 4, "n_rays": rays, "frames_per_task": PROBE_TASK, "workers": 1, "seed": 0}}
            cfg = config_from_dict(data, "prt init probe", base_dir=config_dir)
            blocks: list[float] = []
            t0 = time.perf_counter()
            run_bake(cfg, progress=False, on_block=lambda st, out=blocks: out.append(st.seconds / max(st.frames, 1)))
            wall = time.perf_counter() - t0
            per_frame = float(sorted(blocks)[len(blocks) // 2])  # the median block (the first builds the context)
            traced.append((rays, per_frame / par, wall - PROBE_FRAMES * per_frame + POOL_START_SECONDS))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    (r0, t0_, f0), (r1, t1_, f1) = traced
    b = max((t1_ - t0_) / (r1 - r0), 0.0)
    a = max(t0_ - b * r0, 1e-6)
    return Probe(max(0.5 * (f0 + f1), 0.0), a, b, fit_workload(), load_seconds, PROBE_FRAMES,
                 [(r, t) for r, t, _ in traced])


def _cores() -> int:
    """The CPU cores this process may use (the bake's pool starts one worker per core)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def grid_units(train: dict[str, Any]) -> float:
    """The MLP grid's cost relative to 2 neuron counts x 2 alphas, 100 CV iterations x 4 folds + 200 final ones."""
    folds = int(train.get("folds", 4))
    return (len(train["neurons"]) * len(train["mlp_alphas"]) * (train["cv_iter"] * folds + train["max_iter"])
            / (2 * 2 * (100 * 4 + 200)))


def _frames(seconds: float, fps: float) -> int:
    return int(math.floor(seconds * fps + 1e-9)) + 1


def plan_budget(items: list[Item], split: Split, pr: Probe, vertices: int, rays: int, fps: float,
                cap: float | None, order: int = 4, full_grid: bool | None = None) -> Budget:
    """The frames and the estimated seconds of one rung: ``rays`` per vertex, clips sampled at ``fps``, each whole
    clip cut to ``cap`` seconds (``None``: whole), plus :data:`RANDOM_SHARE` of the training frames as random
    poses; ``full_grid`` the fits' grid (``None``: full from :data:`FULL_GRID_FRAMES` frames on)."""
    train = heldout = 0
    heldout_names = {e if isinstance(e, str) else e["name"] for e in split.heldout}
    for i in items:
        s = i.seconds if cap is None else min(i.seconds, cap)
        if len(items) == 1:  # a within-clip split: its ranges are not cut
            train += _frames(i.seconds * (1 - TAIL_SHARE), fps)
            heldout += _frames(i.seconds * TAIL_SHARE, fps)
        elif i.name in heldout_names:
            heldout += _frames(s, fps)
        else:
            train += _frames(s, fps)
    rnd = int(round(RANDOM_SHARE * train))
    frames = train + heldout + rnd
    full = frames >= FULL_GRID_FRAMES if full_grid is None else full_grid
    return Budget(rays, fps, cap, frames, rnd, pr.bake_seconds(frames, rays),
                  pr.train_seconds(train + rnd, frames, vertices, order * order, grid_units(train_grid(full))), full)


def choose_budget(items: list[Item], split: Split, pr: Probe, vertices: int, seconds: float,
                  order: int = 4) -> Budget:
    """The first :data:`LADDER` rung whose estimate (:func:`plan_budget`) fits ``seconds`` - with the full grid
    where it has the frames for it, else with the small grid; else the last rung, small grid, with every whole clip
    cut to the longest duration that fits (bisection; a single clip's split is never cut)."""
    for rays, fps in LADDER:
        b = plan_budget(items, split, pr, vertices, rays, fps, None, order)
        if b.total_s <= seconds:
            return b
        if b.full_grid:
            b = plan_budget(items, split, pr, vertices, rays, fps, None, order, full_grid=False)
            if b.total_s <= seconds:
                return b
    rays, fps = LADDER[-1]
    if len(items) == 1:
        return plan_budget(items, split, pr, vertices, rays, fps, None, order, full_grid=False)
    lo, hi = 0.0, max(i.seconds for i in items)
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        fits = plan_budget(items, split, pr, vertices, rays, fps, mid, order, full_grid=False).total_s <= seconds
        lo, hi = (mid, hi) if fits else (lo, mid)
    return plan_budget(items, split, pr, vertices, rays, fps, max(lo, 1.0 / fps), order, full_grid=False)


def _capped(entries: list[Any], cap: float | None) -> list[Any]:
    """Split entries with each whole clip cut to its first ``cap`` seconds (a range entry keeps its own range)."""
    if cap is None:
        return entries
    return [{"clip": e, "times": f"0:{cap:.3g}", "name": e} if isinstance(e, str) else e for e in entries]


def config_data(name: str, path: Path, out: Path, character: Character, items: list[Item], split: Split,
                budget: Budget, rescale: bool) -> dict[str, Any]:
    """The config as a plain dict (paths relative to ``out``'s directory)."""
    base = out.resolve().parent

    def rel(p: Path) -> str:
        p = p.resolve()
        if os.path.commonpath([p, base]) == p.anchor:  # nothing in common but the root: an absolute path
            return p.as_posix()
        return Path(os.path.relpath(p, base)).as_posix()

    ch: dict[str, Any] = {"source": rel(path)}
    if rescale:
        ch["height"] = DEFAULT_HEIGHT
    ch["fps"] = budget.fps
    motions = [{"file": rel(i.file), "name": i.name} for i in items if i.file is not None]
    if motions:
        ch["motions"] = motions
    ch["train_clips"] = _capped(split.train, budget.cap_seconds)
    ch["random_poses"] = budget.random_poses
    ch["random_perturb_deg"] = 20.0
    ch["heldout_clips"] = _capped(split.heldout, budget.cap_seconds)
    ch["seed"] = 0
    return {
        "name": name,
        "character": ch,
        "bake": {"order": 4, "n_rays": budget.rays, "below_horizon": "one", "transfer": False, "frames_per_task": 8,
                 "workers": 0, "seed": 0},
        "train": {"kinds": ["linear", "quadratic", "mlp"], "default_kind": "mlp", "input_variance": 0.90,
                  "output_variance": 0.95, "whiten_inputs": False, "folds": 4, **train_grid(budget.full_grid),
                  "seed": 0},
    }


def train_grid(full: bool) -> dict[str, Any]:
    """The fits' hyper-parameter grid: the configs' full grid (``configs/mocap.yaml``), or a smaller one (for fewer
    than :data:`FULL_GRID_FRAMES` frames - few frames support few parameters - or a budget the full grid misses)."""
    if full:
        return {"alphas": [0.001, 0.01, 0.1, 1.0, 10.0, 100.0], "mlp_alphas": [0.1, 1.0, 10.0, 100.0],
                "neurons": [4, 8, 16], "cv_iter": 200, "max_iter": 500}
    return {"alphas": [0.01, 0.1, 1.0, 10.0, 100.0], "mlp_alphas": [1.0, 10.0], "neurons": [4, 8], "cv_iter": 100,
            "max_iter": 200}


def _flow(v: Any) -> str:
    """One YAML flow value."""
    import yaml

    return yaml.safe_dump(v, default_flow_style=True, width=10_000, sort_keys=False).strip().removesuffix("...").strip()


def config_text(data: dict[str, Any], path: Path, items: list[Item], split: Split, budget: Budget, pr: Probe,
                vertices: int, height: float, rescale: bool, minutes: float, run_dir: str) -> str:
    """The config as commented YAML (the same values as ``data``); ``run_dir`` as the next commands name it."""
    ch, bake, train = data["character"], data["bake"], data["train"]
    traced = ", ".join(f"{r} rays {t * 1e3:.1f} ms" for r, t in pr.traced)
    lines = [
        f"# Written by `prt init {path.name}`: {vertices} vertices, rest height {height:.3g} file units.",
        f"# Split: {split.why}.",
        f"# Budget: --minutes {minutes:g} for bake + train on this machine. Probe: two real bakes of "
        f"{pr.probe_frames} frames: {traced} per frame",
        f"#   (start-up {pr.bake_fixed:.1f} s; loading + retargeting {pr.load_seconds:.1f} s); the fit's workload "
        f"{pr.fit_seconds * 1e3:.0f} ms (reference {REFERENCE_FIT_SECONDS * 1e3:.0f} ms).",
        f"#   Estimate: bake {budget.bake_s / 60:.1f} min + train {budget.train_s / 60:.1f} min = "
        f"{budget.total_s / 60:.1f} min for {budget.frames} frames at {budget.rays} rays, {budget.fps:g} fps.",
        f"# prt bake CONFIG && prt train CONFIG && prt export {run_dir} && prt compare {run_dir}",
        f"name: {data['name']}",
        "character:",
        f"  source: {_flow(ch['source'])}   # a relative path is relative to this file",
    ]
    if rescale:
        lines.append(f"  height: {ch['height']}             # the file is {height:.3g} units tall: scaled to "
                     f"{DEFAULT_HEIGHT} m")
    lines.append(f"  fps: {ch['fps']}                # clip sampling rate of the bake (chosen by the budget)")
    from prt_torch.rig.lowpoly import LOW_POLY_VERTICES, suggested_levels

    if vertices < LOW_POLY_VERTICES:
        levels = suggested_levels(vertices)
        lines.append(f"  # subdivide: {levels}           # low-poly ({vertices} vertices): shade a subdivided copy "
                     f"(~{vertices * 4 ** levels} vertices; the budget above did not count it)")
    if "motions" in ch:
        lines.append("  motions:                 # retargeted onto the character (prt_torch.rig.retarget)")
        by_name = {i.name: i for i in items}
        for m in ch["motions"]:
            i = by_name[m["name"]]
            lines.append(f"    - {_flow(m)}   # {i.seconds:.1f} s, category {i.category}")
    lines.append(f"  train_clips: {_flow(ch['train_clips'])}")
    lines.append(f"  random_poses: {ch['random_poses']}        # perturbed frames of the training clips only "
                 f"({RANDOM_SHARE:.0%} of them)")
    lines.append(f"  random_perturb_deg: {ch['random_perturb_deg']}  # no joint limits in glTF: each joint turned "
                 f"by up to this")
    lines.append(f"  heldout_clips: {_flow(ch['heldout_clips'])}   # never seen in training")
    lines.append(f"  seed: {ch['seed']}")
    lines.append("bake:")
    lines.append(f"  order: {bake['order']}")
    lines.append(f"  n_rays: {bake['n_rays']}              # chosen by the budget (ladder: prt_torch.commands.init."
                 f"LADDER)")
    for k in ("below_horizon", "transfer", "frames_per_task"):
        lines.append(f"  {k}: {_flow(bake[k])}")
    lines.append(f"  workers: {bake['workers']}               # one per CPU core")
    lines.append(f"  seed: {bake['seed']}")
    lines.append("train:                     # prt train: linear, quadratic, per-cluster tanh MLP "
                 "(prt_torch/fit/config.py)")
    for k, v in train.items():
        lines.append(f"  {k}: {_flow(v)}")
    return "\n".join(lines) + "\n"
