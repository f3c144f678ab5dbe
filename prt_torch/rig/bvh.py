"""BVH motion capture (CMU style) -> skeleton arrays and a :class:`~prt_torch.rig.clip.Clip` (numpy + scipy).

Format: ``HIERARCHY`` with ``ROOT``/``JOINT`` blocks (``OFFSET``, ``CHANNELS n <names>``) and
``End Site`` leaves (kept as end offsets, not joints), then ``MOTION``, ``Frames:``,
``Frame Time:`` and one row of channel values per frame. Rotation channels are Euler angles in
degrees applied in the listed order as intrinsic rotations (``Zrotation Yrotation Xrotation`` ->
``R = R_z @ R_y @ R_x``); position channels replace the joint's offset
(``local = T(position) @ R``; without position channels ``local = T(offset) @ R``).

The BVH world is y up; the root is converted to the z-up world with ``(x, y, z) -> (x, -z, y)``.
Lengths are multiplied by ``scale`` (CMU files are in their own units; ``scale=0.056444`` gives
metres for the CMU database conversion).

Parsing is a tokenizer plus a small grammar: the motion section starts at the ``MOTION`` keyword
where the grammar expects a keyword after the last closing brace (a joint may be called ``MOTION``
or ``LeftMOTION``). Every malformed input (truncation, unbalanced braces, unknown or repeated
channels, non-finite numbers, missing ``Frames:``/``Frame Time:``, a non-positive frame time, a row
with the wrong number of values, a frame count that does not match the rows) raises
:class:`~prt_torch.errors.PrtError` with one line naming it; poses beyond ``MAX_POSE_BYTES`` are refused.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from prt_torch.errors import PrtError, check
from prt_torch.rig.clip import Clip
from prt_torch.rig.rotations import Y_UP_TO_Z_UP
from prt_torch.rig.skeleton import forward_kinematics

#: the most bytes of local joint transforms (``frames x joints x 4 x 4`` float64) a BVH file may expand to.
MAX_POSE_BYTES = 1 << 30
_KEYWORDS = frozenset({"HIERARCHY", "ROOT", "JOINT", "End", "Site", "OFFSET", "CHANNELS", "MOTION", "{", "}"})
_TOKEN = re.compile(r"\S+")

_AXES = {"Xrotation": "X", "Yrotation": "Y", "Zrotation": "Z"}
_POS = {"Xposition": 0, "Yposition": 1, "Zposition": 2}


@dataclass
class BvhSkeleton:
    """A BVH skeleton: ``joint_names`` (J), ``parents (J,)``, ``offsets (J, 3)`` (scaled, BVH y-up frame),
    ``end_sites``: list of ``(joint index, offset (3,))``, and ``bind_local (J, 4, 4)``: the zero-channel
    pose (``T(offset)``; the root additionally converted to z-up), and ``channels``: each joint's channel names
    in file order."""

    joint_names: list[str]
    parents: np.ndarray
    offsets: np.ndarray
    end_sites: list[tuple[int, np.ndarray]]
    bind_local: np.ndarray
    channels: list[list[str]] = field(default_factory=list)

    def bind_world(self) -> np.ndarray:
        """``(J, 4, 4)`` world transforms of the zero-channel pose (z-up)."""
        return forward_kinematics(self.parents, self.bind_local[None])[0]


def _number(tok: str, what: str, name: str) -> float:
    try:
        x = float(tok)
    except ValueError:
        raise PrtError(f"{name}: {what}: expected a number, got {tok[:30]!r}") from None
    check(bool(np.isfinite(x)), f"{name}: {what} is not finite ({tok[:30]})")
    return x


def _parse_hierarchy(text: str, name: str) -> tuple[list[str], list[int], list[np.ndarray], list[list[str]],
                                                      list[tuple[int, np.ndarray]], int]:
    """``HIERARCHY`` grammar -> ``(names, parents, offsets, channels, end sites (unscaled), motion start)``.

    ``motion start`` is the character offset just after the ``MOTION`` keyword, recognised only where a
    keyword is expected outside every brace, so a joint name containing ``MOTION`` is just a name.
    """
    toks = _TOKEN.finditer(text)

    def nxt(expect: str) -> re.Match[str]:
        m = next(toks, None)
        check(m is not None, f"{name}: truncated BVH file (expected {expect})")
        assert m is not None
        return m

    first = next(toks, None)
    check(first is not None and first.group() == "HIERARCHY", f"{name}: not a BVH file (no HIERARCHY/MOTION sections)")
    names: list[str] = []
    parents: list[int] = []
    offsets: list[np.ndarray] = []
    channels: list[list[str]] = []
    end_sites: list[tuple[int, np.ndarray]] = []
    stack: list[int] = []  # joint indices of the open blocks, -1 for an End Site
    while True:
        m = next(toks, None)
        if m is None:
            check(not stack, f"{name}: truncated BVH hierarchy ({len(stack)} unclosed braces, no MOTION)")
            raise PrtError(f"{name}: not a BVH file (no HIERARCHY/MOTION sections)")
        t = m.group()
        if t == "MOTION" and not stack:
            check(len(names) > 0, f"{name}: empty BVH hierarchy (no ROOT joint)")
            return names, parents, offsets, channels, end_sites, m.end()
        if t in ("ROOT", "JOINT"):
            if t == "ROOT":
                check(not stack, f"{name}: ROOT inside another joint's block")
            else:
                check(bool(stack) and stack[-1] >= 0, f"{name}: JOINT outside a ROOT/JOINT block")
            jn = nxt("a joint name").group()
            check(jn not in ("{", "}"), f"{name}: {t} without a name")
            check(nxt("'{'").group() == "{", f"{name}: expected '{{' after {t} {jn[:40]}")
            names.append(jn)
            parents.append(stack[-1] if stack else -1)
            offsets.append(np.zeros(3))
            channels.append([])
            stack.append(len(names) - 1)
        elif t == "End":
            check(nxt("'Site'").group() == "Site", f"{name}: expected 'End Site'")
            check(bool(stack) and stack[-1] >= 0, f"{name}: End Site outside a joint block")
            check(nxt("'{'").group() == "{", f"{name}: expected '{{' after End Site")
            stack.append(-1)
        elif t == "}":
            check(bool(stack), f"{name}: unbalanced braces (a '}}' closes nothing)")
            stack.pop()
        elif t == "OFFSET":
            check(bool(stack), f"{name}: OFFSET outside a joint block")
            off = np.array([_number(nxt("3 OFFSET values").group(), "OFFSET", name) for _ in range(3)])
            if stack[-1] >= 0:
                offsets[stack[-1]] = off
            else:
                end_sites.append(([s for s in stack if s >= 0][-1], off))
        elif t == "CHANNELS":
            check(bool(stack) and stack[-1] >= 0, f"{name}: CHANNELS outside a joint block")
            joint = stack[-1]
            count = nxt("a channel count").group()
            check(count.isdigit() and int(count) <= 6, f"{name}: joint {names[joint][:40]!r}: bad channel count "
                                                       f"{count[:20]!r} (expected 0-6)")
            chans = [nxt(f"{count} channel names").group() for _ in range(int(count))]
            for c in chans:
                check(c in _AXES or c in _POS, f"{name}: unknown BVH channel {c[:30]!r}")
            check(len(set(chans)) == len(chans), f"{name}: joint {names[joint][:40]!r} repeats a channel: {chans}")
            channels[joint] = chans
        else:
            raise PrtError(f"{name}: unexpected token {t[:30]!r} in BVH hierarchy")


def _parse_motion(text: str, nchan: int, name: str) -> tuple[np.ndarray, float]:
    """The motion section after ``MOTION`` -> ``(data (F, nchan) float64, frame time)``."""
    lines = [ln.strip() for ln in text.splitlines()]
    lines = [ln for ln in lines if ln]
    check(len(lines) > 0 and lines[0].startswith("Frames:"), f"{name}: missing 'Frames:' line")
    frames = lines[0][len("Frames:"):].strip()
    check(frames.isdigit() and int(frames) > 0, f"{name}: bad frame count {frames[:30]!r} (expected an integer > 0)")
    nframes = int(frames)
    check(len(lines) > 1 and re.match(r"Frame\s+Time:", lines[1]) is not None, f"{name}: missing 'Frame Time:' line")
    ft = lines[1].split(":", 1)[1].strip()
    frame_time = _number(ft, "Frame Time", name)
    check(frame_time > 0, f"{name}: Frame Time must be > 0, got {ft[:30]}")
    rows = lines[2:]
    try:
        data = np.array(" ".join(rows).split(), dtype=np.float64)
    except ValueError:
        raise PrtError(f"{name}: non-numeric value in the BVH motion data") from None
    check(bool(np.all(np.isfinite(data))), f"{name}: motion data contains NaN or inf")
    check(len(rows) == nframes, f"{name}: expected {nframes} frames, found {len(rows)} motion rows"
                                f"{' (truncated?)' if len(rows) < nframes else ''}")
    widths = np.array([len(r.split()) for r in rows])
    bad = np.flatnonzero(widths != nchan)
    if bad.size:
        raise PrtError(f"{name}: motion row {int(bad[0]) + 1} has {int(widths[bad[0]])} values, expected {nchan} "
                       f"channels")
    return data.reshape(nframes, nchan), frame_time


def load_bvh(path: str | os.PathLike[str], scale: float = 1.0, name: str | None = None) -> tuple[BvhSkeleton, Clip]:
    """Parse a BVH file -> ``(BvhSkeleton, Clip)``; the clip's fps is ``1 / Frame Time``.

    Raises :class:`PrtError` (one line) for a missing or malformed file (see the module docstring).
    """
    from scipy.spatial.transform import Rotation

    path = Path(path)
    check(path.is_file(), f"BVH file not found: {path}")
    check(bool(np.isfinite(scale)) and scale > 0, f"BVH scale must be > 0, got {scale}")
    text = path.read_text(errors="replace")
    names, parents, offsets, channels, end_sites, motion_at = _parse_hierarchy(text, path.name)
    nchan = sum(len(c) for c in channels)
    check(nchan > 0, f"{path.name}: the BVH hierarchy has no channels")
    j = len(names)
    nrows = sum(1 for ln in text[motion_at:].splitlines() if ln.strip())
    need = max(nrows - 2, 1) * j * 16 * 8
    check(need <= MAX_POSE_BYTES, f"{path.name}: {max(nrows - 2, 1)} frames x {j} joints would take {need / 2**30:.3g} "
                                  f"GiB of joint transforms (limit {MAX_POSE_BYTES / 2**30:.0f} GiB)")
    data, frame_time = _parse_motion(text[motion_at:], nchan, path.name)
    nframes = data.shape[0]
    fps = 1.0 / frame_time
    check(bool(np.isfinite(fps)), f"{path.name}: Frame Time {frame_time:g} is too small")

    with np.errstate(all="ignore"):
        off = np.array(offsets) * scale
        ends = [(k, e * scale) for k, e in end_sites]
        check(bool(np.all(np.isfinite(off))), f"{path.name}: scaled joint offsets overflow")
        local = np.tile(np.eye(4), (nframes, j, 1, 1))
        col = 0
        for k, chans in enumerate(channels):
            trans = np.tile(off[k], (nframes, 1))
            rot_axes = ""
            rot_cols = []
            for c in chans:
                if c in _POS:
                    trans[:, _POS[c]] = data[:, col] * scale
                else:
                    rot_axes += _AXES[c]
                    rot_cols.append(col)
                col += 1
            if rot_axes:
                local[:, k, :3, :3] = Rotation.from_euler(rot_axes, data[:, rot_cols], degrees=True).as_matrix()
            local[:, k, :3, 3] = trans
        check(bool(np.all(np.isfinite(local))), f"{path.name}: motion values overflow (NaN or inf transforms)")
    c4 = np.eye(4)
    c4[:3, :3] = Y_UP_TO_Z_UP
    par = np.array(parents, dtype=np.int64)
    roots = par < 0
    local[:, roots] = c4 @ local[:, roots]
    bind = np.tile(np.eye(4), (j, 1, 1))
    bind[:, :3, 3] = off
    bind[roots] = c4 @ bind[roots]
    skel = BvhSkeleton(names, par, off, ends, bind, [list(c) for c in channels])
    return skel, Clip(name or path.stem, fps, local)
