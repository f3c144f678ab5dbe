"""ONNX export and verification: pose -> visibility, RPO shading and fused graphs, parity with torch.

Heavy imports (torch) happen inside the functions; ``import prt_torch.export`` stays light.
"""

from __future__ import annotations

from typing import Any

__all__ = ["export_run"]


def export_run(*args: Any, **kwargs: Any) -> dict[str, Any]:
    """See :func:`prt_torch.export.run.export_run`."""
    from prt_torch.export.run import export_run as _export_run

    return _export_run(*args, **kwargs)
