"""Atomic file writing: every artifact is written to a temporary sibling, then renamed.

A crash (even SIGKILL) therefore leaves either the old file or the new one, never a torn one. What a
killed writer does leave is its temporary sibling, named ``.<name>.<host>-<pid>.<random><suffix>``
(``<host>``: 6 hex digits of the host name's hash, ``<pid>``: the writer's process id, ``<random>``: the
8 characters of :func:`tempfile.mkstemp`; files of older versions lack the ``<host>-<pid>.`` tag).
:func:`parse_temporary` reads such a name back and :func:`stale_temporaries` finds the ones that are
safe to delete (rule in its docstring); no reader ever opens them (readers open exact names).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import socket
import tempfile
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

_UMASK = os.umask(0)
os.umask(_UMASK)

#: fault injection for tests: when set, called as ``before_replace(tmp, path)`` after the temporary of
#: every atomic write is complete and before it is renamed onto ``path`` (a kill test makes it SIGKILL
#: the process at the k-th write; see tests/test_run_integrity.py)
before_replace: Callable[[Path, Path], None] | None = None

#: temporaries of other hosts / untagged ones (older versions) count as stale after this many seconds
STALE_AGE_S = 3600.0

_RANDOM = r"[a-z0-9_]{8}"
_TAGGED = re.compile(rf"^\.(?P<target>.+)\.(?P<host>[0-9a-f]{{6}})-(?P<pid>\d+)\.{_RANDOM}(?P<suffix>(\..*)?)$")
_LEGACY = re.compile(rf"^\.(?P<target>.+)\.{_RANDOM}(?P<suffix>(\..*)?)$")


def host_tag() -> str:
    """6 hex digits identifying this host in temporary names."""
    return hashlib.sha1(socket.gethostname().encode()).hexdigest()[:6]


def temp_prefix(path: str | os.PathLike[str]) -> str:
    """The ``mkstemp`` prefix of ``path``'s temporaries written by this process: ``.<name>.<host>-<pid>.``."""
    return f".{Path(path).name}.{host_tag()}-{os.getpid()}."


@dataclass(frozen=True)
class Temporary:
    """A parsed temporary file name: the ``target`` name it was to become, and its writer (``host``,
    ``pid``; ``None`` for untagged names of older versions)."""

    path: Path
    target: str
    host: str | None
    pid: int | None


def parse_temporary(path: str | os.PathLike[str]) -> Temporary | None:
    """``path`` as an :func:`atomic_path` temporary, or ``None`` when its name is not one."""
    p = Path(path)
    for rx in (_TAGGED, _LEGACY):
        m = rx.match(p.name)
        if m and m.group("target").endswith(m.group("suffix")):
            d = m.groupdict()
            return Temporary(p, d["target"], d.get("host"), int(d["pid"]) if d.get("pid") else None)
    return None


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


def stale_temporaries(directories: Iterable[str | os.PathLike[str]],
                      targets: Iterable[str | os.PathLike[str]] = (), now: float | None = None) -> list[Path]:
    """Temporaries in ``directories`` (not recursive) that are safe to delete.

    The rule: a temporary is stale when (1) it is one of a file in ``targets`` (the caller is about to
    write that file, so any earlier writer of it is gone or is superseded), or (2) its writer process is
    gone (tagged with this host and a process id that no longer exists; never the current process), or (3)
    it was written on another host or by an older, untagged version and is older than :data:`STALE_AGE_S`.
    A temporary of a live writer is never stale unless its target is in ``targets``.
    """
    now = time.time() if now is None else now
    want: dict[Path, set[str]] = {}
    for t in targets:
        t = Path(t)
        want.setdefault(t.parent.resolve(), set()).add(t.name)
    me, host = os.getpid(), host_tag()
    out = []
    for d in directories:
        d = Path(d)
        if not d.is_dir():
            continue
        names = want.get(d.resolve(), set())
        for p in sorted(d.iterdir()):
            tmp = parse_temporary(p) if p.name.startswith(".") else None
            if tmp is None or not p.is_file():
                continue
            if tmp.target in names and tmp.pid != me:
                out.append(p)
            elif tmp.host == host and tmp.pid is not None:
                if tmp.pid != me and not _alive(tmp.pid):
                    out.append(p)
            else:
                with contextlib.suppress(FileNotFoundError):
                    if now - p.stat().st_mtime > STALE_AGE_S:
                        out.append(p)
    return out


def remove_stale_temporaries(directories: Iterable[str | os.PathLike[str]],
                             targets: Iterable[str | os.PathLike[str]] = ()) -> list[Path]:
    """Delete :func:`stale_temporaries` (a file already gone is skipped); returns the removed paths."""
    removed = []
    for p in stale_temporaries(directories, targets):
        with contextlib.suppress(FileNotFoundError):
            p.unlink()
            removed.append(p)
    return removed


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str], suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success it is renamed onto ``path``.

    ``suffix`` defaults to ``path``'s own suffix so that writers that infer the format from the
    extension (imageio, torch.save, onnx) still work. On error the temporary file is removed and
    ``path`` is left untouched. The temporary is named by :func:`temp_prefix` (see the module doc).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=temp_prefix(path), suffix=suffix if suffix is not None else path.suffix,
                               dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    os.chmod(tmp_path, 0o666 & ~_UMASK)  # mkstemp makes 0600; give artifacts the usual permissions
    try:
        yield tmp_path
        if before_replace is not None:
            before_replace(tmp_path, path)
        os.replace(tmp_path, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (fsync'd temp file + rename)."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())


def atomic_write_text(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path: str | os.PathLike[str], obj: Any) -> None:
    """Write ``obj`` as indented JSON to ``path`` atomically."""
    atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=True) + "\n")


def read_npz_with_meta(path: str | os.PathLike[str], what: str) -> tuple[dict[str, Any], dict[str, Any]]:
    """The arrays of an ``.npz`` written with a JSON ``meta`` entry, and that metadata; a missing or unreadable
    file is a one-line :class:`~prt_torch.errors.PrtError` naming ``what`` (e.g. ``"character"``) and the path."""
    import numpy as np

    from prt_torch.errors import DamagedArtifact, MissingArtifact

    path = Path(path)
    if not path.is_file():
        raise MissingArtifact(f"{what} file not found: {path}")
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
        meta = json.loads(str(data["meta"]))
    except (OSError, ValueError, KeyError) as e:
        raise DamagedArtifact(f"not a {what} .npz file: {path} ({type(e).__name__})") from None
    return data, meta
