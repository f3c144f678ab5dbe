"""Conventions every layer shares, defined once (rank 0: no numpy, no pydantic).

* :data:`BelowHorizon` / :data:`BELOW_HORIZON`: what the local-frame SH visibility is below the horizon (no ray
  is shot there): ``"zero"`` (docs/DESIGN.md) or ``"one"`` (seed 003 eq. 1). The bake records it
  (``bake.below_horizon``), export.json copies it, and every reader follows it
  (:func:`prt_torch.sh.product.mask_below_horizon` is the one rule applying it).
"""

from __future__ import annotations

from typing import Literal

#: the below-horizon visibility conventions (the type of ``bake.below_horizon``)
BelowHorizon = Literal["zero", "one"]
#: the same as a tuple, in this order (messages list them so)
BELOW_HORIZON: tuple[BelowHorizon, ...] = ("zero", "one")
