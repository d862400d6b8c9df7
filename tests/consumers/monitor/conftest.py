"""Helpers of stackgen-monitor's tests: paths and real processes (tests/support/processes.py).

CTest runs these files with Debian's /usr/bin/python3 -m pytest and sets STACKGEN_SOURCE_DIR,
STACKGEN_BIN_DIR and PYTHONPATH (the build's python/ folder)."""

import os
import sys

import pytest

SOURCE = os.environ.get("STACKGEN_SOURCE_DIR",
                        os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(
                            os.path.abspath(__file__))))))
sys.path.insert(0, os.path.join(SOURCE, "tests", "support"))
import configs  # noqa: E402  (tests/support/configs.py)
import processes as support  # noqa: E402  (tests/support/processes.py)

BIN = os.environ.get("STACKGEN_BIN_DIR", os.path.join(SOURCE, "build", "bin"))
TINY_CONFIG = os.path.join(SOURCE, "tests", "fixtures", "logs", "tiny.pbtxt")
free_url = support.free_url


def quick_config(folder):
    """The tiny config with one lighting environment, in `folder` (tests/support/configs.py)."""
    return configs.quick_config(folder, TINY_CONFIG)


@pytest.fixture
def processes(tmp_path):
    """Starts programs (argv, name) and kills those still running at the end of the test."""
    yield from support.started(tmp_path)
