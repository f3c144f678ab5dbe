"""Pose -> visibility models: regressors batched over clusters and the end-to-end module.

``VisibilityModel`` (pose ``(B, A)`` -> visibility ``(B, V, C)``), ``load_model(run_dir, kind=None)``.
"""

from prt_torch.models.projection import GlobalUnprojection, InputProjection, OutputUnprojection
from prt_torch.models.regressors import (
    REGRESSORS,
    LinearRegressor,
    MLPRegressor,
    QuadraticRegressor,
    quadratic_features,
)
from prt_torch.models.visibility import (
    KINDS,
    VisibilityModel,
    link_default,
    load_metadata,
    load_model,
    load_model_file,
    model_path,
    packed_state,
    save_model,
)

__all__ = [
    "KINDS",
    "REGRESSORS",
    "GlobalUnprojection",
    "InputProjection",
    "LinearRegressor",
    "MLPRegressor",
    "OutputUnprojection",
    "QuadraticRegressor",
    "VisibilityModel",
    "load_metadata",
    "load_model",
    "link_default",
    "load_model_file",
    "model_path",
    "packed_state",
    "quadratic_features",
    "save_model",
]
