import sys

from prt_torch.cli import main

sys.exit(main())
