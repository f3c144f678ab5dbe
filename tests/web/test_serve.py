"""``prt web --serve``'s server (:class:`prt_torch.web.serve.SiteServer`) serves the site and nothing else: requests
that climb out of it (``..``, percent-encoded and double-encoded, absolute paths, the absolute-form request target)
and symlinks inside the site that point out of it get 403/404, never the outside file's content.

Requests go over a raw socket, so that no client normalises the path; the server runs on 127.0.0.1, an ephemeral
port, and every socket has a timeout. No browser is needed.
"""

from __future__ import annotations

import os
import socket
from collections.abc import Iterator
from pathlib import Path

import pytest

from prt_torch.web.serve import HOST, SiteServer

SECRET = b"prt-secret-outside-the-site-0123456789"
PAGE = b"<!doctype html><title>site</title>inside"
#: seconds for connecting and for every read of one request
TIMEOUT = 10.0


def raw_get(port: int, target: str) -> tuple[int, bytes]:
    """``(status, body)`` of ``GET target`` sent byte for byte (status 0: the server closed without answering)."""
    with socket.create_connection((HOST, port), timeout=TIMEOUT) as s:
        s.sendall(f"GET {target} HTTP/1.1\r\nHost: {HOST}:{port}\r\nConnection: close\r\n\r\n".encode("latin-1"))
        data = b""
        while chunk := s.recv(65536):
            data += chunk
    if not data:
        return 0, b""
    head, _, body = data.partition(b"\r\n\r\n")
    return int(head.split(b"\r\n", 1)[0].split()[1]), body


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[SiteServer, Path]]:
    """One server for the module: a site ``tmp/site`` beside a secret file and folder ``tmp/outside``; symlinks in
    the site point out of it (``leak.txt``, ``leakdir``, ``assets/rel_leak.txt``) and, as a control, within it
    (``alias.html``)."""
    tmp_path = tmp_path_factory.mktemp("serve")
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "secret.txt").write_bytes(SECRET)
    (tmp_path / "secret.txt").write_bytes(SECRET)
    site = tmp_path / "site"
    (site / "assets").mkdir(parents=True)
    (site / "index.html").write_bytes(PAGE)
    (site / "assets" / "data.bin").write_bytes(b"\x01\x02\x03")
    os.symlink(outside / "secret.txt", site / "leak.txt")
    os.symlink(outside, site / "leakdir")
    os.symlink("../../outside/secret.txt", site / "assets" / "rel_leak.txt")  # relative, out of the site
    os.symlink("index.html", site / "alias.html")
    srv = SiteServer(site, port=0).start()
    try:
        yield srv, tmp_path
    finally:
        srv.close()


def test_server_is_local_with_an_ephemeral_port_and_serves_the_site(served: tuple[SiteServer, Path]) -> None:
    srv, _ = served
    assert srv.httpd.server_address[0] == "127.0.0.1" and srv.port > 0
    assert raw_get(srv.port, "/") == (200, PAGE)
    assert raw_get(srv.port, "/index.html") == (200, PAGE)
    assert raw_get(srv.port, "/assets/data.bin") == (200, b"\x01\x02\x03")
    assert raw_get(srv.port, "/alias.html") == (200, PAGE)  # a symlink that stays inside the site is served
    assert raw_get(srv.port, "/assets/%64ata.bin") == (200, b"\x01\x02\x03")  # percent-decoding itself works


TRAVERSALS = [
    "/../secret.txt",
    "/../outside/secret.txt",
    "/../../secret.txt",
    "/assets/../../secret.txt",
    "/%2e%2e/secret.txt",
    "/%2E%2E/outside/secret.txt",
    "/..%2fsecret.txt",
    "/%2e%2e%2fsecret.txt",
    "/assets/..%2f..%2fsecret.txt",
    "/%252e%252e/secret.txt",  # double-encoded
    "/%252e%252e%252fsecret.txt",
    "/..%252fsecret.txt",
    "/.%2e/secret.txt",
    "//../secret.txt",
    "/..\\secret.txt",
    "/%5c..%5csecret.txt",
    "../secret.txt",  # no leading slash
    "/./../secret.txt",
    "/%00/../secret.txt",
    "/secret.txt%00.html",
]


@pytest.mark.parametrize("target", TRAVERSALS)
def test_paths_climbing_out_of_the_site_are_refused(served: tuple[SiteServer, Path], target: str) -> None:
    srv, _ = served
    status, body = raw_get(srv.port, target)
    assert status in (400, 403, 404), (target, status)
    assert SECRET not in body


def test_absolute_paths_are_refused(served: tuple[SiteServer, Path]) -> None:
    srv, root = served
    secret = str((root / "outside" / "secret.txt").resolve())
    for target in (secret, "/" + secret, f"http://{HOST}:{srv.port}{secret}",
                   f"http://{HOST}:{srv.port}/../secret.txt", "/etc/passwd", "file:///etc/passwd"):
        status, body = raw_get(srv.port, target)
        assert status in (400, 403, 404), (target, status)
        assert SECRET not in body and b"root:" not in body, target


@pytest.mark.parametrize("target", ["/leak.txt", "/leakdir/secret.txt", "/leakdir/", "/leakdir",
                                    "/assets/rel_leak.txt", "/%6ceak.txt"])
def test_symlinks_out_of_the_site_are_refused(served: tuple[SiteServer, Path], target: str) -> None:
    srv, _ = served
    status, body = raw_get(srv.port, target)
    assert status in (403, 404), (target, status)
    assert SECRET not in body and b"secret.txt" not in body  # neither the file nor a listing of its folder
