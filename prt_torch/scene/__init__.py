"""Scenes: a ground plane and several characters, with cast shadows (issue 10 item 4; seed 003 sec. 2, 7).

* :mod:`prt_torch.scene.config`: the ``scene:`` config section (ground, characters with offsets and clips);
* :mod:`prt_torch.scene.ground`: the tessellated ground receiver and its constant frame;
* :mod:`prt_torch.scene.scene`: placed, animated characters (:class:`Actor`), posing (the bake's FK + LBS +
  vertex frames), the overlap check, blocker spheres as the floor sees them;
* :mod:`prt_torch.scene.truth`: whole-scene Embree truth (ground + all posed characters, the bake's ``trace_frame``);
* :mod:`prt_torch.scene.compose`: THE composition rule (floor = SHEXP of all spheres; character = learned
  self-visibility x floor half-space x SHEXP of the others), used by the player and ``prt compare``;
* :mod:`prt_torch.scene.occluders`: the run's SHEXP ONNX graph through onnxruntime (no torch).

numpy (+ onnxruntime, Embree for the truth) only: the scene player imports it without torch.
"""
