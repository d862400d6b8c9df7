"""Helpers of the Python feed's tests: paths, free multicast URLs, real processes.

CTest runs these files with Debian's /usr/bin/python3 -m pytest and sets STACKGEN_SOURCE_DIR,
STACKGEN_BIN_DIR and PYTHONPATH (the build's python/ folder)."""

import os
import subprocess
import sys

import pytest

SOURCE = os.environ.get("STACKGEN_SOURCE_DIR",
                        os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(
                            os.path.abspath(__file__))))))
sys.path.insert(0, os.path.join(SOURCE, "tests", "support"))
import configs  # noqa: E402  (tests/support/configs.py)
import processes as support  # noqa: E402  (tests/support/processes.py)

BIN = os.environ.get("STACKGEN_BIN_DIR", os.path.join(SOURCE, "build", "bin"))
# 6 connectors, 160 x 120: small and quick scenes
TINY_CONFIG = os.path.join(SOURCE, "tests", "fixtures", "logs", "tiny.pbtxt")
# 4 scenes of that config (generator 2, seed 11), recorded by tools/make-fixture-logs
TINY_LOG = os.path.join(SOURCE, "tests", "fixtures", "logs", "tiny.lcmlog")


def coco_of_fixture_log(folder, shards=None, count=None):
    """Writes the fixture log's 4 scenes into a COCO folder `folder` with stackgen-coco (labelled
    images standing for photos, or a held-out test set); with `shards`, also webdataset shards
    of that many images (--shards); with `count`, only the first `count` scenes (--count)."""
    made = subprocess.run([os.path.join(BIN, "stackgen-coco"), "--lcm-url",
                           "file://%s?speed=0" % TINY_LOG, "--open-bus", "--out", str(folder)]
                          + (["--shards", str(shards)] if shards else [])
                          + (["--count", str(count)] if count else []),
                          capture_output=True, text=True, timeout=120)
    assert made.returncode == 0, made.stderr
    return str(folder)


def quick_config(folder, source=None, halls=1):
    """The tiny config (or `source`) with `halls` lighting environments, in `folder`
    (tests/support/configs.py)."""
    return configs.quick_config(folder, source or TINY_CONFIG, halls)


free_url = support.free_url


@pytest.fixture
def processes(tmp_path):
    """Starts programs (argv, name) and kills those still running at the end of the test."""
    yield from support.started(tmp_path)


def generator_argv(url, count, cache_dir, *extra, generator_id=0, seed=5, config=None):
    """The command line of a generator of the tiny config (or `config`)."""
    return [os.path.join(BIN, "stackgen"), "--config", config or TINY_CONFIG, "--count", str(count),
            "--seed", str(seed), "--generator-id", str(generator_id), "--lcm-url", url,
            "--cache-dir", str(cache_dir), "--consumer-timeout", "5", *extra]
