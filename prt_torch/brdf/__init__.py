"""BRDFs and reflection product operators (RPOs).

Analytic isotropic BRDFs (:mod:`~prt_torch.brdf.analytic`), MERL measured BRDFs
(:mod:`~prt_torch.brdf.merl`), tabulation + Kautz-McCool SVD factorisation + SH projection
(:mod:`~prt_torch.brdf.factor`) and the RPO object with save/load and a catalogue
(:mod:`~prt_torch.brdf.rpo`). All local-frame (z = normal), numpy only (no torch).
"""

from prt_torch.brdf.analytic import BRDF, BlinnPhong, CookTorrance, Lambert, Phong, Ward
from prt_torch.brdf.factor import (
    FACTOR_ORDERS,
    BRDFFactors,
    SHFactors,
    factor_brdf,
    factor_sh,
    hemisphere_rule,
    project_factors,
    tabulate,
)
from prt_torch.brdf.merl import MerlBRDF, read_merl, write_merl
from prt_torch.brdf.rpo import CATALOGUE, RPO, build_rpo, builtin_brdf, builtin_rpo

__all__ = [
    "BRDF",
    "CATALOGUE",
    "FACTOR_ORDERS",
    "RPO",
    "BRDFFactors",
    "SHFactors",
    "BlinnPhong",
    "CookTorrance",
    "Lambert",
    "MerlBRDF",
    "Phong",
    "Ward",
    "build_rpo",
    "builtin_brdf",
    "builtin_rpo",
    "factor_brdf",
    "factor_sh",
    "hemisphere_rule",
    "project_factors",
    "read_merl",
    "tabulate",
    "write_merl",
]
