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
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from prt_torch.errors import PrtError, check
from prt_torch.rig.clip import Clip
from prt_torch.rig.rotations import Y_UP_TO_Z_UP
from prt_torch.rig.skeleton import forward_kinematics

_AXES = {"Xrotation": "X", "Yrotation": "Y", "Zrotation": "Z"}
_POS = {"Xposition": 0, "Yposition": 1, "Zposition": 2}


@dataclass
class BvhSkeleton:
    """A BVH skeleton: ``joint_names`` (J), ``parents (J,)``, ``offsets (J, 3)`` (scaled, BVH y-up frame),
    ``end_sites``: list of ``(joint index, offset (3,))``, and ``bind_local (J, 4, 4)``: the zero-channel
    pose (``T(offset)``; the root additionally converted to z-up)."""

    joint_names: list[str]
    parents: np.ndarray
    offsets: np.ndarray
    end_sites: list[tuple[int, np.ndarray]]
    bind_local: np.ndarray

    def bind_world(self) -> np.ndarray:
        """``(J, 4, 4)`` world transforms of the zero-channel pose (z-up)."""
        return forward_kinematics(self.parents, self.bind_local[None])[0]


def load_bvh(path: str | os.PathLike[str], scale: float = 1.0, name: str | None = None) -> tuple[BvhSkeleton, Clip]:
    """Parse a BVH file -> ``(BvhSkeleton, Clip)``; the clip's fps is ``1 / Frame Time``."""
    from scipy.spatial.transform import Rotation

    path = Path(path)
    check(path.is_file(), f"BVH file not found: {path}")
    check(bool(np.isfinite(scale)) and scale > 0, f"BVH scale must be > 0, got {scale}")
    text = path.read_text(errors="replace")
    head, sep, motion = text.partition("MOTION")
    check(bool(sep) and "HIERARCHY" in head, f"{path.name}: not a BVH file (no HIERARCHY/MOTION sections)")
    tok = head.split()
    names: list[str] = []
    parents: list[int] = []
    offsets: list[np.ndarray] = []
    channels: list[list[str]] = []
    end_sites: list[tuple[int, np.ndarray]] = []
    stack: list[int] = []
    i = tok.index("HIERARCHY") + 1
    pending_end = False
    try:
        while i < len(tok):
            t = tok[i]
            if t in ("ROOT", "JOINT"):
                names.append(tok[i + 1])
                parents.append(stack[-1] if stack else -1)
                offsets.append(np.zeros(3))
                channels.append([])
                i += 2
            elif t == "End":
                check(tok[i + 1] == "Site", f"{path.name}: expected 'End Site'")
                pending_end = True
                i += 2
            elif t == "{":
                if pending_end:
                    stack.append(-2)  # marker: inside an End Site
                    pending_end = False
                else:
                    check(len(names) > 0, f"{path.name}: '{{' before any joint")
                    stack.append(len(names) - 1)
                i += 1
            elif t == "}":
                check(len(stack) > 0, f"{path.name}: unbalanced braces")
                stack.pop()
                i += 1
            elif t == "OFFSET":
                off = np.array([float(x) for x in tok[i + 1:i + 4]])
                if stack and stack[-1] == -2:
                    owner = [s for s in stack if s >= 0][-1]
                    end_sites.append((owner, off * scale))
                else:
                    offsets[-1] = off
                i += 4
            elif t == "CHANNELS":
                n = int(tok[i + 1])
                chans = tok[i + 2:i + 2 + n]
                for c in chans:
                    check(c in _AXES or c in _POS, f"{path.name}: unknown BVH channel {c!r}")
                channels[-1] = chans
                i += 2 + n
            else:
                raise PrtError(f"{path.name}: unexpected token {t!r} in BVH hierarchy")
    except PrtError:
        raise
    except (IndexError, ValueError):
        raise PrtError(f"{path.name}: malformed BVH hierarchy") from None
    check(len(names) > 0 and not stack, f"{path.name}: empty or unbalanced BVH hierarchy")

    lines = motion.strip().splitlines()
    try:
        check(lines[0].strip().startswith("Frames:"), f"{path.name}: missing 'Frames:' line")
        nframes = int(lines[0].split(":")[1])
        check(lines[1].strip().startswith("Frame Time:"), f"{path.name}: missing 'Frame Time:' line")
        frame_time = float(lines[1].split(":")[1])
        data = np.array(" ".join(lines[2:]).split(), dtype=np.float64)
    except PrtError:
        raise
    except (IndexError, ValueError):
        raise PrtError(f"{path.name}: malformed BVH motion section") from None
    check(frame_time > 0, f"{path.name}: Frame Time must be > 0")
    nchan = sum(len(c) for c in channels)
    check(nframes > 0 and data.size == nframes * nchan,
          f"{path.name}: expected {nframes} frames x {nchan} channels, found {data.size} values")
    check(bool(np.all(np.isfinite(data))), f"{path.name}: motion data contains NaN or inf")
    data = data.reshape(nframes, nchan)

    j = len(names)
    off = np.array(offsets) * scale
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
    c4 = np.eye(4)
    c4[:3, :3] = Y_UP_TO_Z_UP
    par = np.array(parents, dtype=np.int64)
    roots = par < 0
    local[:, roots] = c4 @ local[:, roots]
    bind = np.tile(np.eye(4), (j, 1, 1))
    bind[:, :3, 3] = off
    bind[roots] = c4 @ bind[roots]
    skel = BvhSkeleton(names, par, off, end_sites, bind)
    return skel, Clip(name or path.stem, 1.0 / frame_time, local)
