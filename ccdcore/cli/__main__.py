"""``python -m ccdcore.cli``: the command line, as the ``ccdcore`` script."""
import sys

from .command import main

if __name__ == "__main__":
    sys.exit(main())
