"""tools/train-live: Mask R-CNN trained live on a real generator over multicast, then again from
its recording; and its bad command lines."""

import os
import subprocess
import sys

import numpy as np
import torch

from conftest import BIN, SOURCE, TINY_CONFIG, TINY_LOG

TRAIN_LIVE = os.path.join(SOURCE, "tools", "train_live.py")


def train_live(*args, timeout=600):
    return subprocess.run([sys.executable, TRAIN_LIVE, "--stackgen", os.path.join(BIN, "stackgen"),
                           *map(str, args)], capture_output=True, text=True, timeout=timeout)


def losses(csv):
    """(loss, batch digest) per iteration of a --loss-csv file."""
    with open(csv) as file:
        return [(float(line.split(",")[1]), line.split(",")[2]) for line in file]


# a live run of a few dozen steps on the small config lowers the loss (fixed seeds), prints the
# rates and the reuse factor, and its recording trains again to the same losses, step by step
def test_live_training_lowers_the_loss_and_replays_bit_for_bit(tmp_path):
    log = tmp_path / "run.lcmlog"
    live = train_live("--config", TINY_CONFIG, "--iterations", 24, "--backbone", "resnet18",
                      "--print-every", 8, "--record", log, "--loss-csv", tmp_path / "live.csv")
    assert live.returncode == 0, live.stderr
    assert "produced" in live.stdout and "consumed" in live.stdout and "reuse" in live.stdout
    curve = [loss for loss, _ in losses(tmp_path / "live.csv")]
    assert len(curve) == 24
    assert np.mean(curve[-8:]) < 0.8 * np.mean(curve[:8]), curve

    # the command as train-live prints it: the recorded settings, --iterations included
    assert "train on it again: tools/train-live --replay %s" % log in live.stdout
    replay = train_live("--replay", log, "--loss-csv", tmp_path / "replay.csv")
    assert replay.returncode == 0, replay.stderr
    assert losses(tmp_path / "replay.csv") == losses(tmp_path / "live.csv")


# bad command lines and bad input: one line, exit 2 (usage) or 1 (input), nothing left behind
def test_bad_command_lines(tmp_path):
    result = train_live("--iterations", 0)
    assert result.returncode == 2
    assert result.stderr.startswith("train-live: error: argument --iterations") and \
        result.stderr.count("\n") == 1
    # no abbreviations: "--iteration" is not "--iterations"
    result = train_live("--iteration", 5)
    assert result.returncode == 2 and "unrecognized arguments: --iteration 5" in result.stderr
    result = train_live("--replay", tmp_path / "missing.lcmlog")
    assert result.returncode == 1
    assert "missing.lcmlog" in result.stderr and result.stderr.count("\n") == 1
    taken = tmp_path / "taken.lcmlog"
    taken.write_text("")
    result = train_live("--config", TINY_CONFIG, "--record", taken)
    assert result.returncode == 1 and "exists already" in result.stderr
    assert not os.path.exists(str(taken) + ".train.json")
    result = train_live("--replay", TINY_LOG, "--record", tmp_path / "x.lcmlog")
    assert result.returncode == 2
    if not torch.cuda.is_available():
        result = train_live("--replay", TINY_LOG, "--device", "cuda")
        assert result.returncode == 1 and "no CUDA device" in result.stderr
