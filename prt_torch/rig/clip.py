"""Animation clips: per-frame local joint transforms sampled at a fixed rate (numpy only)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from prt_torch.errors import check
from prt_torch.rig.rotations import matrix_to_quat, quat_to_matrix, slerp
from prt_torch.shapes import check_shape


@dataclass(repr=False)
class Clip:
    """One motion: ``local (F, J, 4, 4)`` float64 joint-local transforms at ``fps`` frames per second.

    Frame ``f`` is at time ``f / fps``; the duration is ``(F - 1) / fps``. Root joints' local
    transforms are in the z-up world (root motion included here; pose features exclude it).
    """

    name: str
    fps: float
    local: np.ndarray

    def __post_init__(self) -> None:
        self.local = np.asarray(self.local, dtype=np.float64)
        check_shape(self.local, "F J 4 4", name=f"clip {self.name!r}: local transforms")
        check(self.local.shape[0] >= 1,
              f"clip {self.name!r}: local transforms must be (F, J, 4, 4), got {self.local.shape}")
        check(bool(np.all(np.isfinite(self.local))), f"clip {self.name!r}: local transforms contain NaN or inf")
        check(bool(np.isfinite(self.fps)) and self.fps > 0, f"clip {self.name!r}: fps must be > 0, got {self.fps}")
        self.fps = float(self.fps)

    def __repr__(self) -> str:
        return f"Clip(name={self.name!r}, fps={self.fps}, F={self.num_frames}, J={self.num_joints})"

    @property
    def num_frames(self) -> int:
        """``F``."""
        return int(self.local.shape[0])

    @property
    def num_joints(self) -> int:
        """``J``."""
        return int(self.local.shape[1])

    @property
    def duration(self) -> float:
        """Seconds from the first to the last frame."""
        return (self.num_frames - 1) / self.fps

    @classmethod
    def from_rotations(cls, name: str, fps: float, rotations: np.ndarray, translations: np.ndarray) -> Clip:
        """Build a clip from local rotations ``(F, J, 3, 3)`` and translations ``(F, J, 3)`` (or ``(J, 3)``)."""
        rotations = np.asarray(rotations, dtype=np.float64)
        check_shape(rotations, "F J 3 3", name=f"clip {name!r}: rotations")
        translations = np.broadcast_to(np.asarray(translations, dtype=np.float64), (*rotations.shape[:2], 3))
        local = np.zeros((*rotations.shape[:2], 4, 4))
        local[..., :3, :3] = rotations
        local[..., :3, 3] = translations
        local[..., 3, 3] = 1.0
        return cls(name, fps, local)

    def resample(self, fps: float) -> Clip:
        """The same motion sampled at ``fps``: rotations slerped, translations and scales lerped.

        Returns ``floor(duration * fps + 1e-9) + 1`` frames starting at t = 0.
        """
        check(bool(np.isfinite(fps)) and fps > 0, f"fps must be > 0, got {fps}")
        if abs(fps - self.fps) < 1e-12 or self.num_frames == 1:
            return Clip(self.name, fps, self.local.copy())
        n = int(np.floor(self.duration * fps + 1e-9)) + 1
        x = np.arange(n) / fps * self.fps  # fractional source frame
        i0 = np.clip(np.floor(x).astype(np.int64), 0, self.num_frames - 1)
        i1 = np.minimum(i0 + 1, self.num_frames - 1)
        t = np.clip(x - i0, 0.0, 1.0)
        a, b = self.local[i0], self.local[i1]
        sa = np.linalg.norm(a[..., :3, :3], axis=-2)
        sb = np.linalg.norm(b[..., :3, :3], axis=-2)
        qa = matrix_to_quat(a[..., :3, :3] / sa[..., None, :])
        qb = matrix_to_quat(b[..., :3, :3] / sb[..., None, :])
        tt = np.broadcast_to(t[:, None], qa.shape[:-1])
        rot = quat_to_matrix(slerp(qa, qb, tt))
        scale = sa + (sb - sa) * tt[..., None]
        out = np.zeros_like(a)
        out[..., :3, :3] = rot * scale[..., None, :]
        out[..., :3, 3] = a[..., :3, 3] + (b[..., :3, 3] - a[..., :3, 3]) * tt[..., None]
        out[..., 3, 3] = 1.0
        return Clip(self.name, fps, out)
