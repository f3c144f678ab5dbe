"""The MuJoCo model of a cloth subject and its stepping (MuJoCo is imported here, lazily, only).

Model (MJCF written by :func:`model_xml`):

* every free cloth vertex is a body with three world-axis slide joints (the ``dof="full"`` layout of
  ``flexcomp``) and its lumped mass (``areal_density`` x a third of the area of its triangles);
* the flag's pinned vertices (its pole column) sit in the world body; the cape's pinned vertices (its top row)
  are kinematic vertex bodies (1 kg, gravity compensated) following the anchor joint's skin matrix;
* the cloth is one ``flex`` (``dim=2``) over those bodies: inextensible edges as the flex equality constraint
  (``solref`` time constant ``edge_timeconst`` timesteps, critically damped), MuJoCo's 2D shell bending
  (``elasticity`` young / poisson / thickness / damping, ``elastic2d="bend"``), collision radius ``radius``,
  no self collision;
* the cape's body: one kinematic body per joint carrying capsules (:class:`prt_torch.cloth.body.Capsules`),
  its pose the joint's skin matrix (the capsules are given in bind-pose world coordinates); capsules collide
  with the cloth only;
* kinematic bodies are heavy free bodies (gravity compensated) whose pose and velocity are overwritten before
  every step (:meth:`Engine.step`): the pose of the substep's start, the velocity that reaches its end. Unlike
  mocap bodies (teleported, velocity 0 to the solver) they move WITH their constraints and contacts, so the
  damping of the edge constraints at the pinned row and of the body contacts acts on relative velocities;
* CG constraint solver (``iterations``), semi-implicit Euler, ``timestep = 1 / (fps * substeps)``, gravity
  ``-g z``; MuJoCo's fluid model off (``density = viscosity = 0``): the air drag is
  :func:`prt_torch.cloth.wind.triangle_drag`, applied as ``qfrc_applied`` on the vertex dofs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from prt_torch.cloth.subject import ClothSubject
from prt_torch.cloth.wind import WindField, triangle_drag
from prt_torch.errors import PrtError

#: mass (kg) of a kinematic vertex body (the cape's pinned row)
KINEMATIC_MASS = 1.0


def _f(a: np.ndarray) -> str:
    return " ".join(f"{float(x):.9g}" for x in np.ravel(a))


def vertex_masses(subject: ClothSubject) -> np.ndarray:
    """``(N,)`` lumped vertex masses (kg): areal density x a third of the incident triangles' area."""
    p, f = subject.cloth_rest, subject.cloth_faces
    area = 0.5 * np.linalg.norm(np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]]), axis=1)
    m = np.zeros(len(p))
    for c in range(3):
        m += np.bincount(f[:, c], weights=area / 3.0, minlength=len(p))
    return subject.cloth.areal_density * m


def timestep(subject: ClothSubject) -> float:
    """The MuJoCo timestep (s): one output frame is ``substeps`` steps."""
    return 1.0 / (subject.fps * subject.cloth.substeps)


def model_xml(subject: ClothSubject) -> str:
    """The MJCF of the subject's simulation (module docstring)."""
    c = subject.cloth
    dt = timestep(subject)
    pinned = np.zeros(len(subject.cloth_rest), bool)
    pinned[subject.pinned] = True
    mass = vertex_masses(subject)
    inertia = 1e-9
    kin = '<freejoint/><inertial pos="0 0 0" mass="1000" diaginertia="10 10 10"/>'
    static = pinned & (subject.body is None)  # the flag's pole: in the world body
    bodies, names = [], []
    local = np.zeros_like(subject.cloth_rest)
    local[static] = subject.cloth_rest[static]
    for i, (x, pin) in enumerate(zip(subject.cloth_rest, pinned, strict=True)):
        names.append("world" if static[i] else f"v{i}")
        if not static[i]:
            mi, grav = (KINEMATIC_MASS, ' gravcomp="1"') if pin else (max(mass[i], 1e-9), "")
            bodies.append(f'<body name="v{i}" pos="{_f(x)}"{grav}><joint type="slide" axis="1 0 0"/><joint '
                          f'type="slide" axis="0 1 0"/><joint type="slide" axis="0 0 1"/><inertial pos="0 0 0" '
                          f'mass="{mi:.9g}" diaginertia="{inertia} {inertia} {inertia}"/></body>')
    collide = subject.capsules is not None
    if collide:
        caps = subject.capsules
        assert caps is not None
        for j in np.unique(caps.joint):
            geoms = "".join(f'<geom type="capsule" fromto="{_f(caps.a[k])} {_f(caps.b[k])}" '
                            f'size="{caps.radius[k]:.9g}" friction="{c.friction:.9g} 0.005 0.0001" contype="2" '
                            'conaffinity="0"/>'
                            for k in np.flatnonzero(caps.joint == j))
            bodies.append(f'<body name="bone{j}" gravcomp="1">{kin}{geoms}</body>')
    tc = max(c.edge_timeconst * dt, 2.0 * dt)
    contact = (f'<contact contype="0" conaffinity="2" selfcollide="none" internal="false" condim="{c.condim}" '
               f'friction="{c.friction:.9g}" solref="{max(c.contact_timeconst, 2 * dt):.9g} 1" '
               f'solimp="0.9 0.95 0.001"/>' if collide else
               '<contact contype="0" conaffinity="0" selfcollide="none" internal="false"/>')
    return f"""<mujoco model="cloth">
<option timestep="{dt:.12g}" solver="{c.solver}" iterations="{c.iterations}" ls_iterations="10" integrator="Euler"
        gravity="0 0 {-c.gravity:.9g}" density="0" viscosity="0"/>
<worldbody>
{chr(10).join(bodies)}
</worldbody>
<deformable>
<flex name="cloth" dim="2" radius="{c.radius:.9g}" body="{' '.join(names)}" vertex="{_f(local)}"
      element="{_f(subject.cloth_faces)}">
<elasticity young="{c.young:.9g}" poisson="{c.poisson:.9g}" thickness="{c.thickness:.9g}" damping="{c.damping:.9g}"
            elastic2d="bend"/>
{contact}
</flex>
</deformable>
<equality><flex flex="cloth" solref="{tc:.9g} 1" solimp="0.95 0.99 0.001"/></equality>
</mujoco>"""


@dataclass
class Kinematics:
    """Kinematic targets of one instant: the pinned cloth vertices ``pinned (P, 3)`` (world; what the pin body
    puts them at) and the kinematic collider bodies ``bone_pos (B, 3)``, ``bone_quat (B, 4)`` (MuJoCo order w, x,
    y, z; one per collider joint, B = 0 for the flag)."""

    pinned: np.ndarray
    bone_pos: np.ndarray
    bone_quat: np.ndarray

    def lerp(self, other: Kinematics, s: float) -> Kinematics:
        """``(1 - s) self + s other`` (quaternions: normalised lerp along the shorter arc)."""
        q1 = np.where((np.sum(self.bone_quat * other.bone_quat, -1) < 0)[:, None], -other.bone_quat, other.bone_quat)
        q = (1.0 - s) * self.bone_quat + s * q1
        q /= np.maximum(np.linalg.norm(q, axis=-1, keepdims=True), 1e-18)
        return Kinematics((1.0 - s) * self.pinned + s * other.pinned,
                          (1.0 - s) * self.bone_pos + s * other.bone_pos, q)


class Engine:
    """One compiled MuJoCo cloth model; :meth:`reset` before each sequence (the state after a reset is always the
    same, so a sequence is deterministic)."""

    def __init__(self, subject: ClothSubject) -> None:
        try:
            import mujoco
        except ModuleNotFoundError as exc:  # pragma: no cover - the cloth extra
            raise PrtError(f"the cloth simulation needs MuJoCo ({exc}): pip install 'prt-torch[cloth]'") from None
        self.mujoco = mujoco
        self.subject = subject
        try:
            self.model = mujoco.MjModel.from_xml_string(model_xml(subject))
        except ValueError as exc:
            raise PrtError(f"MuJoCo refused the cloth model: {str(exc).splitlines()[0][:200]}") from None
        self.data = mujoco.MjData(self.model)
        m = self.model
        n = len(subject.cloth_rest)
        free = np.ones(n, bool)
        free[subject.pinned] = False
        self.free = np.flatnonzero(free)  # cloth indices of the free vertices
        ids = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"v{i}") for i in self.free], dtype=np.int64)
        pin_ids = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"v{i}") for i in subject.pinned]
                           if subject.body is not None else [], dtype=np.int64)
        self.pin_q = m.jnt_qposadr[m.body_jntadr[pin_ids]][:, None] + np.arange(3)
        self.pin_v = m.jnt_dofadr[m.body_jntadr[pin_ids]][:, None] + np.arange(3)
        self.pin_x0 = np.asarray(m.body_pos[pin_ids], dtype=np.float64)
        self.qadr = m.jnt_qposadr[m.body_jntadr[ids]][:, None] + np.arange(3)
        self.dadr = m.jnt_dofadr[m.body_jntadr[ids]][:, None] + np.arange(3)
        self.x0 = np.asarray(m.body_pos[ids], dtype=np.float64)
        caps = subject.capsules
        self.bones = np.unique(caps.joint) if caps is not None else np.zeros(0, np.int64)
        kin = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"bone{j}") for j in self.bones]
        self.kin_q = np.asarray([m.jnt_qposadr[m.body_jntadr[b]] for b in kin], dtype=np.int64)[:, None] + np.arange(7)
        self.kin_v = np.asarray([m.jnt_dofadr[m.body_jntadr[b]] for b in kin], dtype=np.int64)[:, None] + np.arange(6)
        self.pinned_x = np.asarray(subject.cloth_rest[subject.pinned], dtype=np.float64)
        self.current = Kinematics(self.pinned_x.copy(), np.zeros((0, 3)), np.zeros((0, 4)))
        self.dt = float(m.opt.timestep)
        from scipy.sparse import csr_matrix

        f = subject.cloth_faces
        self.scatter = csr_matrix((np.ones(f.size), (f.ravel(), np.repeat(np.arange(len(f)), 3))),
                                  shape=(n, len(f)))  # (N, T): sum over a vertex's triangles

    @property
    def steps_done(self) -> int:
        return int(round(self.data.time / self.dt))

    def reset(self) -> None:
        self.mujoco.mj_resetData(self.model, self.data)

    def set_kinematics(self, k: Kinematics, target: Kinematics | None = None) -> None:
        """Put the kinematic bodies at ``k`` with the velocity that reaches ``target`` in one step (0 without)."""
        d = self.data
        self.current = k if target is None else target
        if len(self.pin_q):
            d.qpos[self.pin_q] = k.pinned - self.pin_x0
            d.qvel[self.pin_v] = 0.0 if target is None else (target.pinned - k.pinned) / self.dt
        if len(self.kin_q):
            d.qpos[self.kin_q] = np.concatenate([k.bone_pos, k.bone_quat], axis=1)
            vel = np.zeros((len(self.kin_q), 6))
            if target is not None:
                from scipy.spatial.transform import Rotation

                vel[:, :3] = (target.bone_pos - k.bone_pos) / self.dt
                r0 = Rotation.from_quat(k.bone_quat[:, [1, 2, 3, 0]])
                r1 = Rotation.from_quat(target.bone_quat[:, [1, 2, 3, 0]])
                vel[:, 3:] = (r0.inv() * r1).as_rotvec() / self.dt  # body frame, as MuJoCo's free joints
            d.qvel[self.kin_v] = vel

    def positions(self) -> np.ndarray:
        """``(N, 3)`` float64 cloth vertex positions now (pinned: their mocap positions)."""
        x = np.empty((len(self.subject.cloth_rest), 3))
        x[self.free] = self.x0 + self.data.qpos[self.qadr]
        x[self.subject.pinned] = self.current.pinned
        return x

    def velocities(self) -> np.ndarray:
        """``(N, 3)`` float64 vertex velocities (pinned: 0)."""
        v = np.zeros((len(self.subject.cloth_rest), 3))
        v[self.free] = self.data.qvel[self.dadr]
        return v

    def step(self, wind: WindField, t: float, scale: float = 1.0) -> None:
        """One MuJoCo step at time ``t`` (s) with the drag of ``wind`` (its velocity times ``scale``)."""
        c = self.subject.cloth
        if c.air_density > 0:
            x, v = self.positions(), self.velocities()
            faces = self.subject.cloth_faces
            w = scale * wind((x[faces[:, 0]] + x[faces[:, 1]] + x[faces[:, 2]]) / 3.0, t)
            f_tri = triangle_drag(x, v, faces, w, c.air_density, c.drag, c.skin_friction) / 3.0
            self.data.qfrc_applied[self.dadr] = (self.scatter @ f_tri)[self.free]
        self.mujoco.mj_step(self.model, self.data)

    def warnings(self) -> list[str]:
        """Names of MuJoCo warnings raised since the last reset (bad qacc: the solver diverged)."""
        mj = self.mujoco
        out = []
        for w in (mj.mjtWarning.mjWARN_BADQACC, mj.mjtWarning.mjWARN_BADQPOS, mj.mjtWarning.mjWARN_BADQVEL,
                  mj.mjtWarning.mjWARN_CNSTRFULL, mj.mjtWarning.mjWARN_CONTACTFULL):
            if self.data.warning[int(w)].number > 0:
                out.append(str(w).split(".")[-1])
        return out


def quat_wxyz(rot: np.ndarray) -> np.ndarray:
    """``(..., 4)`` unit quaternions (w, x, y, z) of rotation matrices ``(..., 3, 3)``."""
    from scipy.spatial.transform import Rotation

    r = np.asarray(rot, dtype=np.float64)
    q = Rotation.from_matrix(r.reshape(-1, 3, 3)).as_quat()  # x, y, z, w
    return np.concatenate([q[:, 3:], q[:, :3]], axis=1).reshape(*r.shape[:-2], 4)


def engine_kinematics(engine: Engine | Any, skin: np.ndarray | None) -> Kinematics:
    """The kinematic targets for skin matrices ``(J, 4, 4)`` (``None``: the flag, pins at rest)."""
    subject = engine.subject
    if skin is None:
        return Kinematics(engine.pinned_x.copy(), np.zeros((0, 3)), np.zeros((0, 4)))
    m = np.asarray(skin, dtype=np.float64)
    a = m[subject.anchor]
    pinned = engine.pinned_x @ a[:3, :3].T + a[:3, 3]
    bones = m[engine.bones]
    return Kinematics(pinned, bones[:, :3, 3].copy(), quat_wxyz(bones[:, :3, :3]))
