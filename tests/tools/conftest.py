"""Paths shared by the Python tools' tests. CTest runs these files with Debian's /usr/bin/python3
-m pytest and sets STACKGEN_SOURCE_DIR, STACKGEN_BIN_DIR and PYTHONPATH (the build's python/
folder)."""

import os

SOURCE = os.environ.get("STACKGEN_SOURCE_DIR",
                        os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(
                            __file__)))))
BIN = os.environ.get("STACKGEN_BIN_DIR", os.path.join(SOURCE, "build", "bin"))
# 6 connectors, 160 x 120: small and quick scenes
TINY = os.path.join(SOURCE, "tests", "fixtures", "logs", "tiny.pbtxt")
# 4 scenes of that config (ignore regions kept), recorded by tools/make-fixture-logs
TINY_LOG = os.path.join(SOURCE, "tests", "fixtures", "logs", "tiny.lcmlog")
