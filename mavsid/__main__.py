"""``python -m mavsid``: the same command line as the ``mavsid`` script."""

import sys

from mavsid.cli import main

if __name__ == "__main__":
    sys.exit(main())
