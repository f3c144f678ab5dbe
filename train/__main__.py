"""``python -m train CONFIG [options]``: same as ``prt train``."""

from __future__ import annotations

import sys

from prt_torch.cli import main

if __name__ == "__main__":
    sys.exit(main(["train", *sys.argv[1:]]))
