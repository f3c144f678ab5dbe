"""The browser player: ``prt web RUN --out DIR [--serve] [--check]``.

:mod:`prt_torch.web.site` writes a self-contained static site for an exported run (binary buffers + a JSON
manifest, the visibility ONNX graph for onnxruntime-web, the RPO catalogue, lighting presets and the page
from the repository's ``web/src``); :mod:`prt_torch.web.serve` serves it on 127.0.0.1 with the
cross-origin-isolation headers that wasm threads need; :mod:`prt_torch.web.check` drives headless Chromium
and compares the page's frame with the Python player's.
"""

from prt_torch.web.site import read_manifest, write_site

__all__ = ["read_manifest", "write_site"]
