"""One shape check for numpy arrays and torch tensors alike (modelled on kornia's ``KORNIA_CHECK_SHAPE``).

:func:`check_shape` compares ``x.shape`` (duck-typed: torch is never imported here) with a spec such as
``"B V 3"`` and raises :class:`~prt_torch.errors.PrtError` with one line in one format::

    positions must have shape (B, V, 3), got (2, 5, 4): axis 2 must be 3

Spec tokens (a whitespace- or comma-separated string, or a sequence of ``int`` / ``str``):

* an integer: that exact size;
* a name (``B``, ``V``, ``Frames``): a symbolic size, bound on first use; every later use, in the same call or
  in another call given the same ``dims`` dict, must agree;
* ``_``: any size;
* ``*`` or ``...`` (at most once): any number of axes there (``"* 3"``: at least one axis, the last of size 3);
  messages write it ``...``.
"""

from __future__ import annotations

import numbers
import re
from collections.abc import Sequence
from typing import Any

from prt_torch.errors import PrtError

_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*\Z")


def _tokens(spec: str | Sequence[int | str]) -> list[int | str]:
    raw = spec.replace(",", " ").split() if isinstance(spec, str) else list(spec)
    out: list[int | str] = []
    for t in raw:
        if t == "...":
            t = "*"
        if isinstance(t, numbers.Integral) and not isinstance(t, bool):  # numpy integers too
            out.append(int(t))
        elif isinstance(t, str) and t.lstrip("-").isdigit():
            out.append(int(t))
        elif isinstance(t, str) and (t in ("*", "_") or _NAME.match(t) or not isinstance(spec, str)):
            out.append(t)
        else:
            raise ValueError(f"bad shape spec token {t!r} in {spec!r}")
    if out.count("*") > 1:
        raise ValueError(f"shape spec {spec!r} has more than one '*'")
    return out


def _fmt(items: Sequence[Any]) -> str:
    return "(" + ", ".join("..." if i == "*" else str(i) for i in items) + ("," if len(items) == 1 else "") + ")"


def check_shape(x: Any, spec: str | Sequence[int | str], name: str = "array",
                dims: dict[str, int] | None = None) -> dict[str, int]:
    """Check that ``x.shape`` matches ``spec``; returns the symbolic sizes (``dims``, updated in place, if given).

    Raises :class:`PrtError` with one line, ``<name> must have shape <spec>, got <shape>: <which axis>``,
    for an object without a shape, a wrong rank, a wrong size or a symbolic size that disagrees.
    """
    tokens = _tokens(spec)
    want = _fmt(tokens)
    bound: dict[str, int] = {} if dims is None else dims
    shape = getattr(x, "shape", None)
    if shape is None:
        raise PrtError(f"{name} must have shape {want}, got {type(x).__name__} (not an array)")
    got = tuple(int(s) for s in shape)
    head = f"{name} must have shape {want}, got {_fmt(got)}"
    if "*" in tokens:
        star = tokens.index("*")
        before, after = tokens[:star], tokens[star + 1:]
        if len(got) < len(before) + len(after):
            raise PrtError(f"{head}: must have at least {len(before) + len(after)} dims")
        pairs = list(zip(range(len(before)), before, strict=True))
        pairs += [(len(got) - len(after) + i, t) for i, t in enumerate(after)]
    else:
        if len(got) != len(tokens):
            raise PrtError(f"{head}: must have {len(tokens)} dims")
        pairs = list(enumerate(tokens))
    seen: dict[str, int] = {}  # symbol -> axis bound in this call
    for ax, t in pairs:
        size = got[ax]
        if isinstance(t, int):
            if t >= 0 and size != t:
                raise PrtError(f"{head}: axis {ax} must be {t}")
        elif t != "_":
            if t in bound and bound[t] != size:
                where = f"at axis {seen[t]}" if t in seen else "in an earlier input"
                raise PrtError(f"{head}: axis '{t}' is {size} at axis {ax} but {bound[t]} {where}")
            bound[t] = size
            seen.setdefault(t, ax)
    return bound
