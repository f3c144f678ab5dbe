"""Run ``prt ...`` in a fresh interpreter and check that it never imports torch (the player's install has none)."""

from __future__ import annotations

import subprocess
import sys


def run_cli_without_torch(args: list[str], timeout: float = 120.0) -> None:
    """``prt_torch.cli.main(args)`` in a subprocess: asserts exit status 0 and ``torch`` absent from sys.modules."""
    code = ("import sys\nfrom prt_torch.cli import main\n"
            f"rc = main({args!r})\n"
            "assert rc == 0, rc\nassert 'torch' not in sys.modules, 'torch imported'\nprint('ok')")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0 and "ok" in r.stdout, r.stderr[-2000:]
