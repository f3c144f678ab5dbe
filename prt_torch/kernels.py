"""Pinned BLAS kernels: fits as reproducible across machines as the libraries allow (docs/DESIGN.md,
"Determinism").

A fit's ridge solves, SVDs and L-BFGS steps go through BLAS/LAPACK, whose last bits depend on the kernel the
library picks for the CPU (and on ``OPENBLAS_CORETYPE``); L-BFGS amplifies an ulp into another local optimum.
``prt bake`` (its plan: poses, random-pose samplers), ``prt train`` and ``prt demo`` therefore start with the
same kernel family on every x86-64 machine with AVX2
(OpenBLAS ``Haswell``, MKL ``AVX2``, ATen ``avx2``), chosen through the libraries' own environment variables
before they load (:func:`pin_kernels`). ``PRT_KERNELS=native`` keeps each library's own choice. This module
imports no numeric library: it must run before they load.
"""

from __future__ import annotations

import os
import platform
import sys

#: the environment variable that turns kernel pinning off (``native``)
KERNELS_ENV = "PRT_KERNELS"

#: each library's kernel choice, pinned to one family every x86-64 machine with AVX2 has (set before they load)
PINNED_KERNELS: dict[str, str] = {
    "OPENBLAS_CORETYPE": "Haswell",  # numpy / scipy's OpenBLAS (DYNAMIC_ARCH builds)
    "MKL_CBWR": "AVX2",  # torch's MKL: conditional numerical reproducibility at the AVX2 code path
    "ATEN_CPU_CAPABILITY": "avx2",  # torch's own vectorised kernels (reductions, elementwise)
    "OPENBLAS_L2_SIZE": "512",  # the cache size OpenBLAS assumes where it cannot read it (one value everywhere)
}

#: modules that read those variables when they load: pinning is possible only before any of them is imported
_KERNEL_LIBRARIES = ("numpy", "scipy", "torch", "sklearn")


def _cpu_has_avx2() -> bool:
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as f:
            for line in f:
                if line.startswith("flags"):
                    return " avx2" in line and " fma" in line
    except OSError:
        pass
    return False


def pin_kernels() -> str:
    """Pin the BLAS / LAPACK / ATen kernels of this process (a reproducible bake plan and fit); returns what was done.

    ``"pinned"``: the variables of :data:`PINNED_KERNELS` are set (they override the machine's own values, e.g.
    an ``OPENBLAS_CORETYPE`` set for an older OpenBLAS: ``Haswell`` is the family such settings choose);
    ``"native"``: ``PRT_KERNELS=native`` asked for the libraries' own choice; ``"unsupported"``: not an x86-64
    CPU with AVX2 and FMA; ``"loaded"``: a kernel library was already imported in this process (an in-process
    call, e.g. a test), so its choice stands.
    """
    if os.environ.get(KERNELS_ENV, "").strip().lower() == "native":
        return "native"
    if kernel_state() == "pinned":  # e.g. a worker process started by a pinned one
        return "pinned"
    if platform.machine().lower() not in ("x86_64", "amd64") or not _cpu_has_avx2():
        return "unsupported"
    if any(name in sys.modules for name in _KERNEL_LIBRARIES):
        return "loaded"
    os.environ.update(PINNED_KERNELS)
    return "pinned"


def kernel_state() -> str:
    """``"pinned"`` when this process runs with :data:`PINNED_KERNELS` (set before its libraries loaded, or
    inherited), else ``"native"``: what a fit records beside its results."""
    return "pinned" if all(os.environ.get(k) == v for k, v in PINNED_KERNELS.items()) else "native"
