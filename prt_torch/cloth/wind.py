"""Wind fields and the air drag on a cloth's triangles (numpy; applied to the MuJoCo vertex dofs).

MuJoCo's own fluid model (``opt.wind``/``density``/``viscosity``) acts on the equivalent inertia box or the
geoms of a body; a flex vertex is a point mass without geoms, so it would feel (almost) nothing. The cloth
gets the usual per-triangle drag of cloth simulators instead: with ``u = w(x_t, t) - v_t`` the air velocity
relative to triangle ``t`` (centroid ``x_t``, mean vertex velocity ``v_t``), unit normal ``n_t`` and area
``A_t``::

    F_t = 1/2 rho A_t (C_d (u.n) |u.n| n + C_f |u_T| u_T),     u_T = u - (u.n) n

split equally between the triangle's three vertices (``rho`` = ``cloth.air_density``, ``C_d`` = ``cloth.drag``,
``C_f`` = ``cloth.skin_friction``).

The wind of a :class:`~prt_torch.cloth.config.WindPattern` (direction ``d(t)``, azimuth ``phi`` +
wobble, elevation ``theta``)::

    w(x, t) = (U + G g(t - (x.d0) / max(U, 1))) d(t)

with ``U`` the mean speed, ``G`` the gust amplitude and ``g`` a seeded sum of four sines around the gust
frequency normalised to ``|g| <= 1``: the gusts travel downwind along the cloth (``d0`` the mean direction).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from prt_torch.cloth.config import WindPattern

#: sines per gust signal
N_SINES = 4


@dataclass
class WindField:
    """A deterministic wind: :meth:`__call__` gives ``(N, 3)`` air velocities at points and a time."""

    speed: float
    direction: np.ndarray  # (3,) mean direction d0
    azimuth: float  # radians
    elevation: float  # radians
    gust_amplitude: float
    wobble: float  # radians
    freqs: np.ndarray  # (2, N_SINES) Hz: gust, wobble
    phases: np.ndarray  # (2, N_SINES)
    amps: np.ndarray  # (2, N_SINES), each row sums to 1

    @classmethod
    def still(cls) -> WindField:
        """No wind."""
        z = np.zeros((2, N_SINES))
        return cls(0.0, np.array([1.0, 0.0, 0.0]), 0.0, 0.0, 0.0, 0.0, z + 1.0, z, z + 1.0 / N_SINES)

    @classmethod
    def from_pattern(cls, p: WindPattern, seed: int) -> WindField:
        """The wind of a pattern; ``seed`` (the cloth's) and the pattern's seed fix its random parts."""
        rng = np.random.default_rng([int(seed), int(p.seed)])
        freqs = p.gust_frequency * rng.uniform(0.5, 1.5, size=(2, N_SINES))
        phases = rng.uniform(0.0, 2.0 * np.pi, size=(2, N_SINES))
        amps = rng.uniform(0.5, 1.0, size=(2, N_SINES))
        amps /= amps.sum(axis=1, keepdims=True)
        az, el = np.radians(p.direction_deg), np.radians(p.elevation_deg)
        d0 = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        return cls(float(p.speed), d0, float(az), float(el), float(p.gust_amplitude), np.radians(p.gust_direction_deg),
                   freqs, phases, amps)

    def _signal(self, row: int, t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)
        arg = 2.0 * np.pi * self.freqs[row] * t[..., None] + self.phases[row]
        return np.sin(arg) @ self.amps[row]

    def __call__(self, points: np.ndarray, t: float) -> np.ndarray:
        """``(N, 3)`` wind velocity at ``points (N, 3)`` and time ``t`` seconds."""
        if self.speed == 0.0 and self.gust_amplitude == 0.0:
            return np.zeros_like(points, dtype=np.float64)
        az = self.azimuth + self.wobble * float(self._signal(1, np.asarray(t)))
        d = np.array([np.cos(self.elevation) * np.cos(az), np.cos(self.elevation) * np.sin(az), np.sin(self.elevation)])
        lag = (np.asarray(points, dtype=np.float64) @ self.direction) / max(self.speed, 1.0)
        mag = self.speed + self.gust_amplitude * self._signal(0, t - lag)
        return mag[:, None] * d[None, :]


def triangle_drag(x: np.ndarray, v: np.ndarray, faces: np.ndarray, wind: np.ndarray, air_density: float,
                  drag: float, skin_friction: float) -> np.ndarray:
    """``(T, 3)`` drag force of each triangle (module docstring).

    Args:
        x, v: ``(N, 3)`` vertex positions and velocities.
        faces: ``(T, 3)`` triangles.
        wind: ``(T, 3)`` air velocity at each triangle.
    """
    p0, p1, p2 = x[faces[:, 0]], x[faces[:, 1]], x[faces[:, 2]]
    c = np.cross(p1 - p0, p2 - p0)
    a2 = np.linalg.norm(c, axis=1)
    n = c / np.maximum(a2, 1e-18)[:, None]
    u = wind - (v[faces[:, 0]] + v[faces[:, 1]] + v[faces[:, 2]]) / 3.0
    un = np.einsum("ij,ij->i", u, n)
    ut = u - un[:, None] * n
    f = drag * (un * np.abs(un))[:, None] * n + skin_friction * np.linalg.norm(ut, axis=1)[:, None] * ut
    return (0.25 * air_density * a2)[:, None] * f  # 1/2 rho A with A = a2 / 2
