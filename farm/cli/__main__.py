"""`python -m farm.cli`: the `farm` command line."""

import sys

from farm.cli import main

if __name__ == "__main__":  # not when a walk over farm's modules imports this one
    sys.exit(main())
