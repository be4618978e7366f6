"""``python -m tapmuscle.cli``: the ``tapmuscle`` command line."""

import sys

from tapmuscle.cli.main import main

sys.exit(main())
