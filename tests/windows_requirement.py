"""The Windows tests' pieces (Wine, the Windows Python, MinGW-w64) may be missing on a developer's machine:
those tests skip there, with the reason. CI sets ``TAPMUSCLE_REQUIRE_WINDOWS=1``, which turns the skip
into a failure (`.ci/run` installs every piece)."""

import os
from typing import NoReturn

import pytest


def unavailable(reason: str) -> NoReturn:
    """Skip the test for ``reason``, or fail it where the Windows tests are required."""
    if os.environ.get("TAPMUSCLE_REQUIRE_WINDOWS") == "1":
        pytest.fail(f"TAPMUSCLE_REQUIRE_WINDOWS=1 but {reason}")
    pytest.skip(reason)
