"""A static file server for a written site, bound to 127.0.0.1 only, with the cross-origin-isolation headers
(``Cross-Origin-Opener-Policy: same-origin``, ``Cross-Origin-Embedder-Policy: require-corp``) under which the
page gets ``SharedArrayBuffer`` and onnxruntime-web runs multi-threaded wasm.

It serves the site and nothing else: a request whose file, once its percent-encoding is decoded, its ``..`` parts
resolved and every symlink followed, is not inside the site's folder (``/../x``, ``/%2e%2e/x``, ``/..%2fx``, an
absolute or absolute-form target, a symlink in the site pointing out of it, a NUL byte) is answered 404 before any
file is opened or any folder listed or redirected to (tests/web/test_serve.py)."""

from __future__ import annotations

import functools
import os
import threading
from http import HTTPStatus
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

from prt_torch.errors import check

HOST = "127.0.0.1"


class _Handler(SimpleHTTPRequestHandler):
    extensions_map = {**SimpleHTTPRequestHandler.extensions_map, ".mjs": "text/javascript",
                      ".js": "text/javascript", ".wasm": "application/wasm", ".glsl": "text/plain",
                      ".onnx": "application/octet-stream", ".bin": "application/octet-stream"}

    def send_head(self) -> Any:
        """Refuse (404) what is not inside the site, then serve as the base class does."""
        if not self._inside_site():
            self.send_error(HTTPStatus.NOT_FOUND, "File not found")
            return None
        return super().send_head()

    def _inside_site(self) -> bool:
        """Whether the file of the request's path, every symlink followed, lies in the site folder (or is it)."""
        try:
            real = os.path.realpath(self.translate_path(self.path))
        except (OSError, ValueError):  # a NUL byte, an unencodable name
            return False
        root = os.path.realpath(self.directory)
        return real == root or real.startswith(root.rstrip(os.sep) + os.sep)

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
