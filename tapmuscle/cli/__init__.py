"""The ``tapmuscle`` command line, the top layer: each subcommand parses its arguments and calls the
layers below (:mod:`tapmuscle.io`, :mod:`tapmuscle.cosim`, :mod:`tapmuscle.diagnosis`,
:mod:`tapmuscle.paper`). ``python -m tapmuscle.cli`` is the same as ``tapmuscle``."""

from tapmuscle.cli.main import build_parser, main

__all__ = ["main", "build_parser"]
