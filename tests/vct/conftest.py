"""Shared scenes of the cone-tracing tests."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture(scope="session")
def posed_character() -> dict[str, np.ndarray]:
    """The built-in character at density 0.25 (~2.9k vertices), frame 10 of ``squat``: positions, unit normals,
    faces."""
    from prt_torch.rig.builtin import make_character

    ch = make_character(0.25)
    poses = ch.pose("squat")
    pos, nrm = ch.skin_mesh(poses.skin[[10]])
    nrm = nrm[0] / np.linalg.norm(nrm[0], axis=1, keepdims=True)
    return {"positions": pos[0].astype(np.float32), "normals": nrm.astype(np.float32),
            "faces": np.asarray(ch.faces), "rest": np.asarray(ch.rest_vertices)}
