"""Paths shared by the research bench's Python tests. CTest runs these files with Debian's
/usr/bin/python3 -m pytest and sets STACKGEN_SOURCE_DIR, STACKGEN_BIN_DIR and PYTHONPATH (the
build's python/ folder)."""

import os

SOURCE = os.environ.get("STACKGEN_SOURCE_DIR",
                        os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(
                            __file__)))))
BIN = os.environ.get("STACKGEN_BIN_DIR", os.path.join(SOURCE, "build", "bin"))
