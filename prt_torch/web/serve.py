"""A static file server for a written site, bound to 127.0.0.1 only, with the cross-origin-isolation headers
(``Cross-Origin-Opener-Policy: same-origin``, ``Cross-Origin-Embedder-Policy: require-corp``) under which the
page gets ``SharedArrayBuffer`` and onnxruntime-web runs multi-threaded wasm."""

from __future__ import annotations

import functools
import os
import threading
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

from prt_torch.errors import check

HOST = "127.0.0.1"


class _Handler(SimpleHTTPRequestHandler):
    extensions_map = {**SimpleHTTPRequestHandler.extensions_map, ".mjs": "text/javascript",
                      ".js": "text/javascript", ".wasm": "application/wasm", ".glsl": "text/plain",
                      ".onnx": "application/octet-stream", ".bin": "application/octet-stream"}

    def end_headers(self) -> None:
        self.send_header("Cross-Origin-Opener-Policy", "same-origin")
        self.send_header("Cross-Origin-Embedder-Policy", "require-corp")
        self.send_header("Cross-Origin-Resource-Policy", "same-origin")
        self.send_header("Cache-Control", "no-store")
        super().end_headers()

    def log_message(self, format: str, *args: object) -> None:  # noqa: A002 - the base class's name
        if os.environ.get("PRT_WEB_LOG"):
            super().log_message(format, *args)


class SiteServer:
    """Serve ``site`` on ``127.0.0.1:port`` (``port=0``: a free port) in a daemon thread; ``url`` once started."""

    def __init__(self, site: str | os.PathLike[str], port: int = 0) -> None:
        site = Path(site)
        check(site.is_dir(), f"site directory not found: {site}")
        handler = functools.partial(_Handler, directory=str(site))
        self.httpd = ThreadingHTTPServer((HOST, int(port)), handler)
        self.port = int(self.httpd.server_address[1])
        self.url = f"http://{HOST}:{self.port}/"
        self._thread: threading.Thread | None = None

    def start(self) -> SiteServer:
        self._thread = threading.Thread(target=self.httpd.serve_forever, name="prt-web", daemon=True)
        self._thread.start()
        return self

    def serve_forever(self) -> None:
        self.httpd.serve_forever()

    def close(self) -> None:
        self.httpd.shutdown() if self._thread is not None else None
        self.httpd.server_close()

    def __enter__(self) -> SiteServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
