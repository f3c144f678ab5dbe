"""Random training poses (seed 003 sec. 5.1: "regularly sampling the space of input parameters").

Three modes (``random_poses(..., mode=...)``), all deterministic in ``seed``:

``"uniform"`` (the default, the original sampler) moves EVERY joint at once:

* Characters with ``joint_limits (J, 3, 2)`` (the built-in humanoid): every joint's bind-relative
  angles ``(a_x, a_y, a_z)`` are drawn independently and uniformly within the limits and composed
  as ``R_bind @ R_x(a_x) @ R_z(a_z) @ R_y(a_y)``; joint translations and the root stay at the bind
  pose. Independent sampling can produce self-intersecting poses (e.g. an arm through the torso);
  that is accepted (visibility is still well defined).
* Characters without limits (glTF/BVH): each random pose starts from a uniformly random frame of a
  uniformly random clip of ``base_clips`` (the source clips the caller passes: TRAINING clips or
  training frame ranges only, never the character's other clips) and every non-root joint's rotation
  is perturbed by a random rotation of angle up to ``perturb_deg`` about a uniformly random axis; the
  root keeps its bind transform. Without source clips this is an error.

``"sparse"`` moves only a FEW joint chains per pose, so that every limb's configuration space is
covered without teaching a cluster correlations with far-away limbs that real motion never has:

* The skeleton is split into chains (:func:`joint_chains`): maximal runs of joints below the root or
  a branching joint, each joint having at most one child (humanoid: spine, neck+head, each arm from
  the clavicle, each leg from the hip).
* Each key pose starts from a base pose, the bind pose or (with probability ``base_clip_prob``) a
  uniformly random frame of one of ``base_clips`` (the caller passes TRAINING clips only; the root
  and every joint outside the chosen chains keep the base frame's transforms), then ``1..max_chains``
  distinct chains (uniform count, uniform choice) get new rotations: uniform within the joint limits
  (as in ``"uniform"``; with probability ``near_base`` per joint, a uniform fraction of the way from
  the base's angles to that sample, to concentrate poses near plausible ones) or, without limits,
  the base rotation times a random rotation of angle up to ``perturb_deg``.
* ``segment > 1`` turns the key poses into continuous trajectories: consecutive key poses are joined
  by ``segment`` frames of per-joint geodesic (slerp) rotation and linear translation interpolation,
  so CV folds blocked by contiguous frame ranges hold out whole motions. ``segment = 1`` gives
  independent poses.

``"cpca"`` resamples the pose space of the training motion (seed 001 sec. 2: clustered PCA of the
poses, stratified Monte Carlo resampling of the PCA coefficients):

* The 6D pose features (:mod:`prt_torch.rig.features`, float64) of every frame of ``base_clips``
  (TRAINING frames only; none is an error) are clustered by k-means (scikit-learn ``KMeans``, seeded
  from ``seed``) into ``cpca_clusters`` clusters (fewer when the frames have fewer distinct poses;
  more clusters than frames is an error), and each cluster gets a PCA of its frames: mean ``mu_c``
  ``(A,)``, the first ``cpca_components`` principal directions ``V_c (m_c, A)`` (``m_c`` = at most
  the cluster's frame count) and the observed coefficient range ``[lo_c, hi_c]`` per component.
* The ``n`` poses are spread evenly over the clusters (in cluster order; the first ``n % k`` clusters
  get one more). A cluster's ``s`` poses are a Latin hypercube in its coefficient box: per component,
  ``[lo, hi]`` is cut into ``s`` equal strata, each stratum gets exactly one sample (a random
  permutation per component pairs the strata across components), jittered uniformly within it.
  Features ``mu_c + z @ V_c`` are mapped back to rotations by Gram-Schmidt (the standard 6D -> SO(3)
  map: normalise column 0, remove its component from column 1 and normalise, column 2 = cross
  product); a degenerate 6D pair (a column of norm < 1e-6) keeps the base frame's rotation.
* Characters with joint limits: every non-root joint's bind-relative angles are clamped to its limits
  (:func:`limit_angles` / :func:`compose_limit_angles`); without limits there is no clamp.
* The root transform and every joint translation (and per-axis scale) come from the BASE frame: the
  cluster's training frame nearest to the sample in the cluster's PCA coefficients (a real training
  frame, so the root is never clamped: it is outside the pose features). Poses come out grouped by
  cluster, in cluster order.

No mode samples from ``character.clips`` on its own: every clip frame a random pose derives from
comes from ``base_clips`` (``Clip`` objects, or names looked up in ``character.clips``), so held-out
motion cannot leak into training (the bake plan,
:func:`prt_torch.bake.plan.make_plan`, is the one place that builds these sources from the split).
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from prt_torch.errors import check
from prt_torch.rig.character import Character
from prt_torch.rig.clip import Clip
from prt_torch.rig.rotations import axis_angle_matrix, rotation_part
from prt_torch.shapes import check_shape

MODES = ("uniform", "sparse", "cpca")


def _axis_rotations(axis: int, angles: np.ndarray) -> np.ndarray:
    e = np.zeros(3)
    e[axis] = 1.0
    return axis_angle_matrix(e, angles)


def compose_limit_angles(angles: np.ndarray) -> np.ndarray:
    """``R_x(a_x) @ R_z(a_z) @ R_y(a_y)`` for angles ``(..., 3)`` = ``(a_x, a_y, a_z)`` radians -> ``(..., 3, 3)``."""
    angles = np.asarray(angles, dtype=np.float64)
    return _axis_rotations(0, angles[..., 0]) @ _axis_rotations(2, angles[..., 2]) @ _axis_rotations(1, angles[..., 1])


def joint_chains(parents: np.ndarray) -> list[list[int]]:
    """Split a skeleton ``parents (J,)`` (``-1`` = root) into chains of non-root joints.

    A chain starts at a child of a root or of a branching joint (two or more children) and follows
    single children until a leaf or a branching joint (which is included and ends the chain). Every
    non-root joint is in exactly one chain; chains are ordered by their first joint.
    """
    parents = np.asarray(parents)
    children: list[list[int]] = [[] for _ in range(parents.shape[0])]
    for c, p in enumerate(parents):
        if p >= 0:
            children[int(p)].append(c)
    starts = [c for c, p in enumerate(parents) if p >= 0 and (parents[p] < 0 or len(children[int(p)]) != 1)]
    chains = []
    for s in starts:
        chain = [s]
        while len(children[chain[-1]]) == 1:
            chain.append(children[chain[-1]][0])
        chains.append(chain)
    return chains


def _random_rotations(rng: np.random.Generator, shape: tuple[int, ...], max_deg: float) -> np.ndarray:
    """Rotations ``shape + (3, 3)`` about uniform axes by angles up to ``max_deg`` (uniform in the ball)."""
    axis = rng.normal(size=shape + (3,))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    ang = np.radians(max_deg) * np.cbrt(rng.random(shape))
    k = np.zeros(shape + (3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -axis[..., 2], axis[..., 1], -axis[..., 0]
    k = k - np.swapaxes(k, -1, -2)
    s, c = np.sin(ang)[..., None, None], np.cos(ang)[..., None, None]
    return np.eye(3) + s * k + (1 - c) * (k @ k)


def limit_angles(character: Character, local: np.ndarray) -> np.ndarray:
    """Bind-relative angles ``(..., J, 3)`` = ``(a_x, a_y, a_z)`` radians of local transforms ``(..., J, 4, 4)``.

    The inverse of ``R_bind @ R_x(a_x) @ R_z(a_z) @ R_y(a_y)`` (intrinsic X-Z-Y Euler angles, scipy).
    """
    rel = np.swapaxes(character.bind_local[..., :3, :3], -1, -2) @ local[..., :3, :3]
    xzy = Rotation.from_matrix(rel.reshape(-1, 3, 3)).as_euler("XZY").reshape(*rel.shape[:-2], 3)
    return xzy[..., [0, 2, 1]]


def _limit_rotations(character: Character, rng: np.random.Generator, n: int, base: np.ndarray | None = None,
                     near_base: float = 0.0) -> np.ndarray:
    """``(n, J, 3, 3)`` local rotations uniform within the joint limits (``R_bind @ R(angles)``).

    With ``base (n, J, 4, 4)`` and ``near_base > 0``: with probability ``near_base`` per (pose, joint)
    the angles are ``base + f * (uniform - base)`` with ``f ~ U(0, 1)`` (between the base and a uniform
    sample: concentrated near the base, within the limits whenever the base is).
    """
    lim = character.joint_limits
    u = rng.random((n, character.num_joints, 3))
    angles = lim[None, :, :, 0] + u * (lim[None, :, :, 1] - lim[None, :, :, 0])
    if base is not None and near_base > 0:
        near = rng.random((n, character.num_joints)) < near_base
        f = np.where(near, rng.random((n, character.num_joints)), 1.0)[..., None]
        b = limit_angles(character, base)
        angles = b + f * (angles - b)
    return character.bind_local[None, :, :3, :3] @ compose_limit_angles(angles)


def _interpolate(keys: np.ndarray, segment: int, n: int) -> np.ndarray:
    """``n`` frames joining key poses ``keys (K, J, 4, 4)``, ``segment`` frames per key-to-key step.

    Rotations: per-joint slerp; translations: linear. Frame ``i * segment`` is key ``i`` exactly.
    """
    k, j = keys.shape[:2]
    idx = np.arange(n)
    seg = np.minimum(idx // segment, k - 2)
    t = (idx - seg * segment) / segment  # (n,) in [0, 1]
    a, b = keys[seg], keys[seg + 1]  # (n, J, 4, 4)
    rel = np.swapaxes(a[..., :3, :3], -1, -2) @ b[..., :3, :3]
    rv = Rotation.from_matrix(rel.reshape(-1, 3, 3)).as_rotvec().reshape(n, j, 3)
    step = Rotation.from_rotvec((rv * t[:, None, None]).reshape(-1, 3)).as_matrix().reshape(n, j, 3, 3)
    out = a.copy()
    out[..., :3, :3] = a[..., :3, :3] @ step
    out[..., :3, 3] = a[..., :3, 3] + t[:, None, None] * (b[..., :3, 3] - a[..., :3, 3])
    return out


def _sparse_poses(character: Character, n: int, rng: np.random.Generator, perturb_deg: float,
                  base_clips: Sequence[Clip], base_clip_prob: float, max_chains: int, segment: int,
                  near_base: float) -> np.ndarray:
    """Local transforms ``(n, J, 4, 4)`` of the ``"sparse"`` mode (see the module docstring)."""
    j = character.num_joints
    chains = joint_chains(character.parents)
    check(len(chains) > 0, f"character {character.name!r} has no non-root joints to pose")
    n_keys = n if segment == 1 else -(-(n - 1) // segment) + 1
    # base poses
    base = np.tile(character.bind_local, (n_keys, 1, 1, 1))
    if base_clips and base_clip_prob > 0:
        use = rng.random(n_keys) < base_clip_prob
        ci = rng.integers(0, len(base_clips), size=n_keys)
        fi = np.floor(rng.random(n_keys) * np.array([base_clips[c].num_frames for c in ci])).astype(np.int64)
        for k in np.nonzero(use)[0]:
            base[k] = base_clips[ci[k]].local[fi[k]]
    # which chains move: a uniform count in 1..max_chains, then a uniform subset of that size
    m = min(max_chains, len(chains))
    count = rng.integers(1, m + 1, size=n_keys)
    order = np.argsort(rng.random((n_keys, len(chains))), axis=1)
    chosen_chain = np.zeros((n_keys, len(chains)), dtype=bool)
    np.put_along_axis(chosen_chain, order, np.arange(len(chains))[None, :] < count[:, None], axis=1)
    joint_chain = np.full(j, -1)
    for c, chain in enumerate(chains):
        joint_chain[chain] = c
    moved = np.zeros((n_keys, j), dtype=bool)
    nonroot = joint_chain >= 0
    moved[:, nonroot] = chosen_chain[:, joint_chain[nonroot]]
    # new rotations for the moved joints
    if character.joint_limits is not None:
        new = _limit_rotations(character, rng, n_keys, base if near_base > 0 else None, near_base)
    else:
        new = base[..., :3, :3] @ _random_rotations(rng, (n_keys, j), perturb_deg)
    keys = base.copy()
    keys[..., :3, :3] = np.where(moved[..., None, None], new, base[..., :3, :3])
    return keys if segment == 1 else _interpolate(keys, segment, n)


@dataclass
class CpcaModel:
    """Clustered PCA of pose features ``(F, A)`` (:func:`fit_cpca`); ``k`` clusters, cluster ``c`` has ``n_c`` frames.

    Attributes:
        labels: ``(F,)`` int64 cluster of each frame (``0..k-1``, every cluster non-empty).
        members: ``k`` arrays ``(n_c,)`` int64, the frames of each cluster (ascending).
        means: ``k`` arrays ``(A,)`` float64, the cluster means.
        bases: ``k`` arrays ``(m_c, A)`` float64 with orthonormal rows, the first ``m_c`` principal directions
            (``m_c = min(components, n_c)``; directions of zero variance have a zero coefficient range).
        coeffs: ``k`` arrays ``(n_c, m_c)`` float64, the members' coefficients ``(x - mean) @ basis.T``.
        lo, hi: ``k`` arrays ``(m_c,)`` float64, the observed coefficient range per component.
    """

    labels: np.ndarray
    members: list[np.ndarray]
    means: list[np.ndarray]
    bases: list[np.ndarray]
    coeffs: list[np.ndarray]
    lo: list[np.ndarray]
    hi: list[np.ndarray]

    @property
    def num_clusters(self) -> int:
        """``k``."""
        return len(self.members)


@dataclass
class CpcaSamples:
    """Resampled pose features (:func:`sample_cpca`), grouped by cluster in cluster order.

    Attributes:
        features: ``(n, A)`` float64 ``mean_c + z @ basis_c`` (before the 6D -> SO(3) map).
        cluster: ``(n,)`` int64 cluster of each sample.
        base: ``(n,)`` int64 the frame nearest each sample among its cluster's members (in PCA coefficients).
    """

    features: np.ndarray
    cluster: np.ndarray
    base: np.ndarray


def fit_cpca(features: np.ndarray, clusters: int, components: int, random_state: int = 0) -> CpcaModel:
    """K-means (scikit-learn, ``random_state``) of ``features (F, A)`` into ``clusters`` clusters, PCA per cluster.

    ``clusters`` is lowered to the number of distinct rows when there are fewer; ``clusters > F`` and
    ``components > A`` are :class:`PrtError`.
    """
    x = np.asarray(features, dtype=np.float64)
    check_shape(x, "F A", name="cpca features")
    check(x.shape[0] >= 1 and x.shape[1] >= 1, f"cpca features must be (F, A), got {x.shape}")
    check(bool(np.all(np.isfinite(x))), "cpca features contain NaN or inf")
    f, a = x.shape
    check(components <= a, f"random pose cpca_components={components} exceeds the pose feature dimension {a} "
                           "(6 per non-root joint)")
    check(clusters <= f, f"random pose cpca_clusters={clusters} exceeds the {f} training frames to cluster")
    k = min(clusters, int(np.unique(x, axis=0).shape[0]))
    if k == 1:
        labels = np.zeros(f, dtype=np.int64)
    else:
        from sklearn.cluster import KMeans

        labels = KMeans(n_clusters=k, n_init=4, random_state=random_state).fit_predict(x)
        labels = np.unique(labels, return_inverse=True)[1].astype(np.int64).reshape(f)  # drop empty clusters
    model = CpcaModel(labels, [], [], [], [], [], [])
    for c in range(int(labels.max()) + 1):
        idx = np.flatnonzero(labels == c)
        mu = x[idx].mean(axis=0)
        _, _, vt = np.linalg.svd(x[idx] - mu, full_matrices=False)
        basis = vt[:min(components, vt.shape[0])]
        z = (x[idx] - mu) @ basis.T
        for lst, v in zip((model.members, model.means, model.bases, model.coeffs, model.lo, model.hi),
                          (idx, mu, basis, z, z.min(axis=0), z.max(axis=0)), strict=True):
            lst.append(v)
    return model


def _nearest_rows(points: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """``(q,)`` index of the nearest row of ``points (p, m)`` to each row of ``queries (q, m)`` (brute force)."""
    p2 = np.sum(points**2, axis=1)
    chunk = max(1, (1 << 22) // max(1, points.shape[0]))
    return np.concatenate([np.argmin(p2[None] - 2.0 * (queries[i:i + chunk] @ points.T), axis=1)
                           for i in range(0, queries.shape[0], chunk)])


def sample_cpca(model: CpcaModel, n: int, rng: np.random.Generator) -> CpcaSamples:
    """``n`` stratified samples of the clusters' coefficient boxes, spread evenly over the clusters.

    Cluster ``c`` gets ``s_c = n // k (+1 for c < n % k)`` samples forming a Latin hypercube of
    ``[lo_c, hi_c]``: per component, each of ``s_c`` equal strata holds exactly one sample, jittered
    uniformly within it (strata paired across components by independent random permutations).
    """
    k = model.num_clusters
    counts = n // k + (np.arange(k) < n % k)
    feats, cluster, base = [], [], []
    for c in range(k):
        s = int(counts[c])
        if s == 0:
            continue
        lo, hi = model.lo[c], model.hi[c]
        stratum = np.argsort(rng.random((s, lo.size)), axis=0)  # (s, m_c) a permutation of 0..s-1 per component
        z = lo + (stratum + rng.random((s, lo.size))) / s * (hi - lo)
        feats.append(model.means[c] + z @ model.bases[c])
        cluster.append(np.full(s, c, dtype=np.int64))
        base.append(model.members[c][_nearest_rows(model.coeffs[c], z)])
    return CpcaSamples(np.concatenate(feats), np.concatenate(cluster), np.concatenate(base))


def six_to_rotations(six: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """Gram-Schmidt 6D -> SO(3): ``six (..., 6)`` = two columns -> rotations ``(..., 3, 3)`` (det +1).

    A pair with a column of norm < 1e-6 (after removing column 0 from column 1) has no defined
    rotation and takes ``fallback (..., 3, 3)`` instead.
    """
    a, b = six[..., :3], six[..., 3:]
    na = np.linalg.norm(a, axis=-1, keepdims=True)
    c0 = a / np.maximum(na, 1e-300)
    b = b - np.sum(c0 * b, axis=-1, keepdims=True) * c0
    nb = np.linalg.norm(b, axis=-1, keepdims=True)
    c1 = b / np.maximum(nb, 1e-300)
    rot = np.stack([c0, c1, np.cross(c0, c1)], axis=-1)
    bad = (na[..., 0] < 1e-6) | (nb[..., 0] < 1e-6)
    return np.where(bad[..., None, None], fallback, rot)


def _cpca_poses(character: Character, n: int, rng: np.random.Generator, clips: Sequence[Clip], clusters: int,
                components: int) -> np.ndarray:
    """Local transforms ``(n, J, 4, 4)`` of the ``"cpca"`` mode (see the module docstring)."""
    nonroot = character.parents >= 0
    check(bool(np.any(nonroot)), f"character {character.name!r} has no non-root joints to pose")
    frames = np.concatenate([c.local for c in clips]).astype(np.float64)  # (F, J, 4, 4) training frames only
    bind_rot = rotation_part(character.bind_local)  # (J, 3, 3)
    rel = (np.swapaxes(bind_rot, -1, -2)[None] @ rotation_part(frames))[:, nonroot]  # (F, J', 3, 3)
    feats = np.concatenate([rel[..., :, 0], rel[..., :, 1]], axis=-1).reshape(frames.shape[0], -1)  # (F, A)
    model = fit_cpca(feats, clusters, components, random_state=int(rng.integers(0, 2**31 - 1)))
    smp = sample_cpca(model, n, rng)
    rot = six_to_rotations(smp.features.reshape(n, -1, 6), rel[smp.base])  # (n, J', 3, 3) bind-relative
    if character.joint_limits is not None:
        lim = character.joint_limits[nonroot]  # (J', 3, 2)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # gimbal lock: the angles still compose to the rotation
            xzy = Rotation.from_matrix(rot.reshape(-1, 3, 3)).as_euler("XZY").reshape(*rot.shape[:-2], 3)
        rot = compose_limit_angles(np.clip(xzy[..., [0, 2, 1]], lim[None, ..., 0], lim[None, ..., 1]))
    local = frames[smp.base]  # root transform, translations and scales of the base frames
    scale = np.linalg.norm(local[..., :3, :3], axis=-2)  # (n, J, 3) column norms
    local[:, nonroot, :3, :3] = (bind_rot[nonroot] @ rot) * scale[:, nonroot, None, :]
    return local


def random_poses(character: Character, n: int, seed: int = 0, perturb_deg: float = 20.0,
                 name: str = "random", fps: float = 30.0, mode: str = "uniform",
                 base_clips: Sequence[str | Clip] = (), base_clip_prob: float = 0.5, max_chains: int = 3,
                 segment: int = 1, near_base: float = 0.0, cpca_clusters: int = 8, cpca_components: int = 8) -> Clip:
    """``n`` random poses of ``character`` as a :class:`Clip` with ``local (n, J, 4, 4)``; deterministic in ``seed``.

    ``base_clips`` are the SOURCE clips of every mode (names of the character's clips or :class:`Clip`
    objects, e.g. a training frame range of a clip; pass training motion only): the only clip frames a
    random pose may start from. Nothing else of the character's clips is ever read.

    ``mode="uniform"``: independent frames moving every joint: within the joint limits (``base_clips``
    unused), or, without limits, a random frame of ``base_clips`` with every non-root joint perturbed by
    up to ``perturb_deg`` degrees (no source clip: :class:`PrtError`).
    ``mode="sparse"``: each key pose moves ``1..max_chains`` joint chains of a base pose (the bind
    pose or, with probability ``base_clip_prob``, a random frame of ``base_clips``), key poses joined by
    ``segment`` interpolated frames (``1``: independent poses); ``near_base``: the probability that a
    moved joint lands between its base angles and the uniform sample (joint limits only).
    ``mode="cpca"``: k-means of the ``base_clips`` frames' pose features into ``cpca_clusters`` clusters, a
    ``cpca_components``-component PCA per cluster, a Latin hypercube of each cluster's observed coefficient
    box (``n`` spread evenly over the clusters), Gram-Schmidt back to rotations, clamped to the joint limits
    when the character has them; root and translations of the nearest training frame (no source clip, more
    clusters than frames or more components than feature dimensions: :class:`PrtError`). See the module
    docstring.
    """
    check(isinstance(n, int | np.integer) and n >= 1, f"number of random poses must be >= 1, got {n}")
    check(mode in MODES, f"unknown random pose mode {mode!r}; expected one of {list(MODES)}")
    check(isinstance(segment, int | np.integer) and segment >= 1, f"random pose segment must be >= 1, got {segment}")
    check(isinstance(max_chains, int | np.integer) and max_chains >= 1,
          f"random pose max_chains must be >= 1, got {max_chains}")
    check(isinstance(cpca_clusters, int | np.integer) and cpca_clusters >= 1,
          f"random pose cpca_clusters must be >= 1, got {cpca_clusters}")
    check(isinstance(cpca_components, int | np.integer) and cpca_components >= 1,
          f"random pose cpca_components must be >= 1, got {cpca_components}")
    check(0.0 <= base_clip_prob <= 1.0, f"random pose base_clip_prob must be in [0, 1], got {base_clip_prob}")
    check(0.0 <= near_base <= 1.0, f"random pose near_base must be in [0, 1], got {near_base}")
    check(np.isfinite(perturb_deg) and perturb_deg >= 0, f"perturb_deg must be finite and >= 0, got {perturb_deg}")
    check(isinstance(base_clips, Sequence) and not isinstance(base_clips, str),
          f"random pose base_clips must be a sequence of clip names or Clips, got {type(base_clips).__name__}")
    clips = [character.clip(c) for c in base_clips]  # unknown names / wrong joint counts: PrtError
    rng = np.random.default_rng(seed)
    j = character.num_joints
    if mode == "cpca":
        check(len(clips) > 0, f"cpca random poses of character {character.name!r} need training clips to resample "
                              "(base_clips is empty)")
        return Clip(name, fps, _cpca_poses(character, n, rng, clips, int(cpca_clusters), int(cpca_components)))
    if mode == "sparse":
        check(character.joint_limits is not None or len(clips) > 0 or perturb_deg > 0,
              "sparse random poses need joint limits, base clips or perturb_deg > 0")
        return Clip(name, fps, _sparse_poses(character, n, rng, perturb_deg, clips, base_clip_prob, max_chains,
                                             segment, near_base))
    local = np.tile(character.bind_local, (n, 1, 1, 1))
    nonroot = character.parents >= 0
    if character.joint_limits is not None:
        rot = _limit_rotations(character, rng, n)
        local[:, nonroot, :3, :3] = rot[:, nonroot]
        return Clip(name, fps, local)
    check(len(clips) > 0, f"character {character.name!r} has no joint limits and no training clip to sample "
                          "random poses from (base_clips is empty)")
    ci = rng.integers(0, len(clips), size=n)
    src = np.stack([clips[c].local[rng.integers(0, clips[c].num_frames)] for c in ci])  # (n, J, 4, 4)
    pert = _random_rotations(rng, (n, j), perturb_deg)
    local[:, nonroot] = src[:, nonroot]
    local[:, nonroot, :3, :3] = src[:, nonroot, :3, :3] @ pert[:, nonroot]
    return Clip(name, fps, local)
