"""``python -m tapmuscle``: the ``tapmuscle`` command line, where the console script is not on PATH
(a notebook's kernel, a venv that is not activated)."""

import sys

from tapmuscle.cli.main import main

if __name__ == "__main__":  # not when a spawned worker process imports the parent's main module
    sys.exit(main())
