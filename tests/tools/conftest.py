"""Paths and process helpers shared by the Python tools' tests. CTest runs these files with Debian's /usr/bin/python3
-m pytest and sets STACKGEN_SOURCE_DIR, STACKGEN_BIN_DIR and PYTHONPATH (the build's python/
folder)."""

import os
import subprocess
import sys
import time

SOURCE = os.environ.get("STACKGEN_SOURCE_DIR",
                        os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(
                            __file__)))))
sys.path.insert(0, os.path.join(SOURCE, "tests", "support"))
import configs  # noqa: E402  (tests/support/configs.py)

BIN = os.environ.get("STACKGEN_BIN_DIR", os.path.join(SOURCE, "build", "bin"))
# 6 connectors, 160 x 120: small and quick scenes
TINY = os.path.join(SOURCE, "tests", "fixtures", "logs", "tiny.pbtxt")
# 4 scenes of that config (ignore regions kept), recorded by tools/make-fixture-logs
TINY_LOG = os.path.join(SOURCE, "tests", "fixtures", "logs", "tiny.lcmlog")


def descendants(pid):
    """The processes `pid` started, and theirs, now."""
    found, parents = [], [pid]
    while parents:
        children = subprocess.run(["pgrep", "-P", str(parents.pop())], capture_output=True,
                                  text=True).stdout.split()
        found += [int(child) for child in children]
        parents += [int(child) for child in children]
    return found


def alive(pid):
    """Whether process `pid` exists and is not a zombie."""
    try:
        with open("/proc/%d/stat" % pid) as file:
            return file.read().rsplit(")", 1)[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def left_running(pids, seconds=60):
    """The command lines of those of `pids` still running after up to `seconds`."""
    deadline = time.monotonic() + seconds
    while any(alive(pid) for pid in pids) and time.monotonic() < deadline:
        time.sleep(0.1)
    left = []
    for pid in pids:
        try:
            with open("/proc/%d/cmdline" % pid) as file:
                left.append(file.read().replace("\0", " ") if alive(pid) else None)
        except FileNotFoundError:
            pass
    return [command for command in left if command]


def quick_config(folder, source=None, halls=1):
    """The tiny config (or `source`) with `halls` lighting environments, in `folder`
    (tests/support/configs.py)."""
    return configs.quick_config(folder, source or TINY, halls)
