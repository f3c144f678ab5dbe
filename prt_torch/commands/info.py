"""``prt info FILE [--fps F] [--json]``: what a character or motion file holds, before anyone has to guess.

``FILE`` is a glTF character (``.glb``/``.gltf``), a BVH motion (``.bvh``) or ``builtin`` (the built-in
humanoid, :mod:`prt_torch.rig.builtin`). Shown:

* glTF: the character name (the file stem, as :func:`prt_torch.rig.gltf.load_gltf` names it), welded
  vertex and face counts, the rest height (z extent, in file units, z up), the skeleton's joints
  (parents first) with their parents, the clips with their frame counts at ``--fps`` (default 30, the
  loader's and the configs' ``character.fps`` default), fps and duration ``(F - 1) / fps`` seconds, and
  every material of the file (name, ``baseColorFactor``, whether it has a base-colour texture,
  ``roughnessFactor``, ``metallicFactor``, spec defaults filled in, and whether the character's meshes use
  it). Clip names follow the loader's documented rule (:mod:`prt_torch.rig.gltf`): a named animation
  keeps its name; an unnamed one is ``animation_<i>`` (``i`` its index in the file's ``animations``
  array); repeated names become ``<name>_2``, ``<name>_3``, ... in file order. These are the names a
  config's ``train_clips``/``heldout_clips`` and ``prt play --clip`` take.
* BVH: the joints with their parents and channel orders (e.g. ``Xposition Yposition Zposition
  Zrotation Yrotation Xrotation``), the frame count and fps (``1 / Frame Time``); its one clip is named
  after the file stem.
* ``builtin``: the humanoid's joints, vertex/face counts and its six clips.

A character with few shading vertices (fewer than :data:`prt_torch.rig.lowpoly.LOW_POLY_VERTICES`) gets one
``warning:`` line on stderr naming the remedy, ``character.subdivide: N`` in the run config
(:func:`prt_torch.rig.lowpoly.low_poly_advice`; per-vertex shadows on large triangles are blotches).

With ``--json`` one JSON object goes to stdout: ``file``, ``kind`` (``gltf``, ``bvh`` or ``builtin``),
``character``, ``vertices``, ``faces``, ``height`` (``null`` for BVH), ``joints`` (``[{"index",
"name", "parent" (name or null), "parent_index" (-1 for a root)}]``, BVH joints also ``channels``),
``clips`` (``[{"name", "frames", "fps", "duration"}]``), ``low_poly`` (the advice line, or ``null``) and
``materials`` (glTF: ``[{"index", "name"
(or null), "base_color_factor" [r, g, b, a], "base_color_texture" (bool), "roughness_factor",
"metallic_factor", "used" (bool)}]``, else ``[]``). A missing file, an unknown extension or a malformed
file is one line ``error: ...`` and exit status 2. Never imports torch.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

HELP = "Show what a character/motion file holds (.glb/.gltf/.bvh or 'builtin'): joints, clips, frames, materials."

#: file suffix -> kind
KINDS = {".glb": "gltf", ".gltf": "gltf", ".bvh": "bvh"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", metavar="FILE", help="a .glb/.gltf character, a .bvh motion, or 'builtin'")
    parser.add_argument("--fps", type=float, default=30.0,
                        help="rate at which glTF animations are sampled into clips (default 30, as in the configs)")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of tables")


def run(args: argparse.Namespace) -> int:
    info = describe(args.file, fps=args.fps)
    if info.get("low_poly"):
        from prt_torch.errors import warn

        warn(info["low_poly"])
    if args.json:
        json.dump(info, sys.stdout)
        sys.stdout.write("\n")
    else:
        _print_tables(info)
    return 0


def describe(file: str, fps: float = 30.0) -> dict[str, Any]:
    """The information ``prt info`` shows, as a JSON-ready dict (see the module docstring for its keys).

    Raises :class:`~prt_torch.errors.PrtError` (one line) for a missing, unknown or malformed file.
    """
    from prt_torch import limits
    from prt_torch.errors import PrtError

    limits.check_float(fps, "--fps", 0.0, limits.MAX_FPS, lo_open=True)
    if file == "builtin":
        return _describe_builtin()
    path = Path(file)
    if not path.exists():
        raise PrtError(f"file not found: {file}")
    if not path.is_file():
        raise PrtError(f"not a file: {file}")
    kind = KINDS.get(path.suffix.lower())
    if kind is None:
        raise PrtError(f"unknown file type {path.suffix or '(none)'!r}: {path.name} "
                       f"(expected .glb, .gltf, .bvh or 'builtin')")
    try:
        return _describe_gltf(path, fps) if kind == "gltf" else _describe_bvh(path)
    except PrtError:
        raise
    except Exception as exc:  # a loader tripping over a malformed file (bad indices, wrong types, ...)
        detail = " ".join(str(exc).split())[:200]
        raise PrtError(f"{path.name}: malformed {'glTF' if kind == 'gltf' else 'BVH'} file "
                       f"({type(exc).__name__}{': ' + detail if detail else ''})") from None


def _joints(names: list[str], parents: Any) -> list[dict[str, Any]]:
    return [{"index": j, "name": n, "parent": names[int(p)] if p >= 0 else None, "parent_index": int(p)}
            for j, (n, p) in enumerate(zip(names, parents, strict=True))]


def _clips(clips: Any) -> list[dict[str, Any]]:
    return [{"name": c.name, "frames": c.num_frames, "fps": c.fps, "duration": c.duration} for c in clips]


def _character_info(file: str, kind: str, character: Any) -> dict[str, Any]:
    import numpy as np

    from prt_torch.rig.lowpoly import low_poly_advice

    return {"file": file, "kind": kind, "character": character.name, "vertices": character.num_vertices,
            "faces": int(character.faces.shape[0]),
            "height": float(np.ptp(character.rest_vertices[:, 2])) if character.num_vertices else 0.0,
            "joints": _joints(character.joint_names, character.parents),
            "clips": _clips(character.clips.values()), "materials": [],
            "low_poly": low_poly_advice(character.num_vertices)}


def _describe_builtin() -> dict[str, Any]:
    from prt_torch.rig.builtin import make_character

    return _character_info("builtin", "builtin", make_character())


def _describe_gltf(path: Path, fps: float) -> dict[str, Any]:
    import pygltflib

    from prt_torch.rig.gltf import load_gltf

    info = _character_info(str(path), "gltf", load_gltf(path, fps=fps))
    gltf = pygltflib.GLTF2().load(str(path))  # load_gltf has parsed it: this succeeds
    info["materials"] = _materials(gltf)
    return info


def _materials(gltf: Any) -> list[dict[str, Any]]:
    """Every material of the file, glTF defaults filled in; ``used``: a primitive of the character's meshes
    (the meshes of the nodes skinned by the first skinned mesh node's skin, as the loader reads them) uses it."""
    nodes = gltf.nodes or []
    skinned = [n for n in nodes if n.mesh is not None and n.skin is not None]
    used: set[int] = set()
    if skinned:
        for n in skinned:
            if n.skin == skinned[0].skin:
                used |= {p.material for p in gltf.meshes[n.mesh].primitives if p.material is not None}
    out = []
    for i, m in enumerate(gltf.materials or []):
        pbr = m.pbrMetallicRoughness
        color = pbr.baseColorFactor if pbr is not None and pbr.baseColorFactor is not None else [1.0, 1.0, 1.0, 1.0]
        rough = pbr.roughnessFactor if pbr is not None and pbr.roughnessFactor is not None else 1.0
        metal = pbr.metallicFactor if pbr is not None and pbr.metallicFactor is not None else 1.0
        out.append({"index": i, "name": m.name or None, "base_color_factor": [float(c) for c in color],
                    "base_color_texture": bool(pbr is not None and pbr.baseColorTexture is not None),
                    "roughness_factor": float(rough), "metallic_factor": float(metal), "used": i in used})
    return out


def _describe_bvh(path: Path) -> dict[str, Any]:
    from prt_torch.rig.bvh import load_bvh

    skel, clip = load_bvh(path)
    joints = _joints(skel.joint_names, skel.parents)
    channels = [list(c) for c in skel.channels]  # the loader's own parse, in its joint order
    for j, ch in zip(joints, channels, strict=True):
        j["channels"] = ch
    return {"file": str(path), "kind": "bvh", "character": clip.name, "vertices": 0, "faces": 0, "height": None,
            "joints": joints, "clips": _clips([clip]), "materials": [], "low_poly": None}


def _short_channels(channels: list[str]) -> str:
    """``Xposition Yposition Zposition Zrotation Yrotation Xrotation`` -> ``pos XYZ rot ZYX``."""
    pos = "".join(c[0] for c in channels if c.endswith("position"))
    rot = "".join(c[0] for c in channels if c.endswith("rotation"))
    return " ".join(p for p in (f"pos {pos}" if pos else "", f"rot {rot}" if rot else "") if p) or "-"


def _print_tables(info: dict[str, Any]) -> None:
    from rich.table import Table

    from prt_torch.progress import make_console

    con = make_console()
    if info["kind"] == "bvh":
        con.print(f"[bold]{info['file']}[/bold]: BVH motion, {len(info['joints'])} joints")
    else:
        con.print(f"[bold]{info['file']}[/bold]: character {info['character']!r}, {info['vertices']:,} vertices, "
                  f"{info['faces']:,} faces, {len(info['joints'])} joints, height {info['height']:.4g} (z up)")
    ct = Table(title="clips (names as configs and `prt play --clip` take them)")
    for col, just in (("name", "left"), ("frames", "right"), ("fps", "right"), ("duration (s)", "right")):
        ct.add_column(col, justify=just)  # type: ignore[arg-type]
    for c in info["clips"]:
        ct.add_row(c["name"], str(c["frames"]), f"{c['fps']:.4g}", f"{c['duration']:.3f}")
    if not info["clips"]:
        ct.add_row("(none)", "", "", "")
    jt = Table(title="joints")
    jt.add_column("#", justify="right")
    jt.add_column("name")
    jt.add_column("parent")
    if info["kind"] == "bvh":
        jt.add_column("channels")
    for j in info["joints"]:
        row = [str(j["index"]), j["name"], j["parent"] if j["parent"] is not None else "-"]
        if info["kind"] == "bvh":
            row.append(_short_channels(j["channels"]))
        jt.add_row(*row)
    con.print(jt)
    if info["kind"] == "gltf":
        mt = Table(title="materials")
        for col in ("#", "name", "baseColorFactor", "texture", "roughness", "metallic", "used"):
            mt.add_column(col)
        for m in info["materials"]:
            mt.add_row(str(m["index"]), m["name"] or "(unnamed)", ", ".join(f"{c:.3g}" for c in m["base_color_factor"]),
                       "yes" if m["base_color_texture"] else "no", f"{m['roughness_factor']:.3g}",
                       f"{m['metallic_factor']:.3g}", "yes" if m["used"] else "no")
        if not info["materials"]:
            mt.add_row("(none)", "", "", "", "", "", "")
        con.print(mt)
    con.print(ct)
