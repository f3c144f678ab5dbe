"""``python -m export RUN [options]`` == ``prt export RUN [options]``."""

from __future__ import annotations

import sys

from prt_torch.cli import main

if __name__ == "__main__":
    sys.exit(main(["export", *sys.argv[1:]]))
