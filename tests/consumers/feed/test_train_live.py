"""tools/train-live: Mask R-CNN trained live on a real generator over multicast, then again from
its recording; and its bad command lines."""

import glob
import os
import shlex
import subprocess
import sys

import numpy as np
import pytest
import torch

from conftest import BIN, SOURCE, TINY_CONFIG, TINY_LOG, coco_of_fixture_log, quick_config

TRAIN_LIVE = os.path.join(SOURCE, "tools", "train_live.py")


def train_live(*args, timeout=600):
    return subprocess.run([sys.executable, TRAIN_LIVE, "--stackgen", os.path.join(BIN, "stackgen"),
                           *map(str, args)], capture_output=True, text=True, timeout=timeout)


def losses(csv):
    """(loss, batch digest) per iteration of a --loss-csv file."""
    with open(csv) as file:
        return [(float(line.split(",")[1]), line.split(",")[2]) for line in file]


# a live run of a few steps on the small config lowers the loss (fixed seeds), prints the rates
# and the reuse factor, and its recording trains again to the same losses, step by step. (Eight
# steps with 16 RoIs an image, the mask head's cost; the margin over seeds: docs/results.md,
# "Tests".)
def test_live_training_lowers_the_loss_and_replays_bit_for_bit(tmp_path):
    log = tmp_path / "run.lcmlog"
    # (a generator of the tiny config with one lighting environment: conftest.quick_config)
    live = train_live("--config", quick_config(tmp_path), "--iterations", 8, "--backbone",
                      "resnet18", "--rois", 16, "--print-every", 2, "--record", log,
                      "--loss-csv", tmp_path / "live.csv")
    assert live.returncode == 0, live.stderr
    assert "produced" in live.stdout and "consumed" in live.stdout and "reuse" in live.stdout
    curve = [loss for loss, _ in losses(tmp_path / "live.csv")]
    assert len(curve) == 8
    assert np.mean(curve[-3:]) < 0.8 * np.mean(curve[:3]), curve

    # the command as train-live prints it: the recorded settings, --iterations included
    assert "train on it again: tools/train-live --replay %s" % log in live.stdout
    replay = train_live("--replay", log, "--loss-csv", tmp_path / "replay.csv")
    assert replay.returncode == 0, replay.stderr
    assert losses(tmp_path / "replay.csv") == losses(tmp_path / "live.csv")


def train_live_in_process(capfd, *args):
    """train_live.main on a command line in this process (torch is loaded once, not once per
    command line): (exit status, stderr). For the command lines it refuses before training."""
    sys.path.insert(0, os.path.dirname(TRAIN_LIVE))
    try:
        import train_live as program
    finally:
        sys.path.remove(os.path.dirname(TRAIN_LIVE))
    capfd.readouterr()
    with pytest.raises(SystemExit) as exited:
        program.main(["--stackgen", os.path.join(BIN, "stackgen"), *map(str, args)])
    return exited.value.code, capfd.readouterr().err


# bad command lines and bad input: one line, exit 2 (usage) or 1 (input), nothing left behind.
# Two as processes (a usage error, and an input error after torch loaded: nothing else on
# stderr), the others through the script's main() in this process
def test_bad_command_lines(tmp_path, capfd):
    result = train_live("--iterations", 0)
    assert result.returncode == 2
    assert result.stderr.startswith("train-live: error: argument --iterations") and \
        result.stderr.count("\n") == 1
    result = train_live("--replay", tmp_path / "missing.lcmlog")
    assert result.returncode == 1
    assert "missing.lcmlog" in result.stderr and result.stderr.count("\n") == 1

    # no abbreviations: "--iteration" is not "--iterations"
    status, stderr = train_live_in_process(capfd, "--iteration", 5)
    assert status == 2 and "unrecognized arguments: --iteration 5" in stderr
    taken = tmp_path / "taken.lcmlog"
    taken.write_text("")
    status, stderr = train_live_in_process(capfd, "--config", TINY_CONFIG, "--record", taken)
    assert status == 1 and "exists already" in stderr
    assert not os.path.exists(str(taken) + ".train.json")
    status, stderr = train_live_in_process(capfd, "--replay", TINY_LOG, "--record",
                                           tmp_path / "x.lcmlog")
    assert status == 2
    if not torch.cuda.is_available():
        status, stderr = train_live_in_process(capfd, "--replay", TINY_LOG, "--device", "cuda")
        assert status == 1 and "no CUDA device" in stderr
    for argv, status, text in (
            (("--mix-fraction", 0.2), 2, "--mix-fraction needs --mix DIR"),
            (("--mix", tmp_path, "--mix-fraction", 1), 2, "argument --mix-fraction: wants a "
             "number in [0, 1), got '1'"),
            (("--eval-every", 5), 2, "--eval-every needs --eval DIR"),
            (("--nproc", 2, "--record", tmp_path / "y.lcmlog"), 2, "--record takes one process"),
            (("--mix", tmp_path / "none"), 1, "--mix: %s: no such folder" % (tmp_path / "none")),
            (("--eval", tmp_path), 1, "--eval: %s: neither a COCO folder" % tmp_path)):
        got, stderr = train_live_in_process(capfd, "--config", TINY_CONFIG, *argv)
        assert got == status and text in stderr, (argv, stderr)
        assert stderr.count("\n") == 1, stderr
    assert not os.path.exists(tmp_path / "y.lcmlog")


# the README's command for several processes, real photos and scores (with the tiny config, a
# small backbone, fewer RoIs and three steps): two DDP ranks (gloo, on the CPU) train on disjoint
# scenes and end with the same parameters; real images are mixed in, and the model is scored at
# the end
def test_readme_command_two_ranks_real_images_and_scores(tmp_path):
    # the README, or the page of docs/ it was moved to: exactly one such line in all
    pages = [os.path.join(SOURCE, "README.md")] + sorted(
        glob.glob(os.path.join(SOURCE, "docs", "*.md")))
    command = []
    for page in pages:
        with open(page) as file:
            command += [line for line in file.read().splitlines()
                        if line.startswith("tools/train-live --nproc 2 ")]
    assert len(command) == 1, command
    coco_of_fixture_log(tmp_path / "photos")
    # a test set of one image: the model in eval mode, untrained, keeps up to 100 detections
    # an image and runs the mask head on each, the slow part of a test on a CPU
    coco_of_fixture_log(tmp_path / "testset", count=1)
    run = subprocess.run(
        [sys.executable, TRAIN_LIVE, "--stackgen", os.path.join(BIN, "stackgen")] +
        shlex.split(command[0])[1:] +
        ["--config", quick_config(tmp_path), "--backbone", "resnet18", "--iterations", "3",
         "--workers", "0", "--reuse", "1", "--mix-fraction", "0.5", "--rois", "16"],
        cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "train-live: 2 ranks (DDP, gloo)" in run.stdout
    # rank 0's 6 samples: 3 scenes and 3 photos; 6 scenes over both ranks, none on two
    assert "2 ranks: 6 samples of 6 distinct scenes, none on two ranks; parameters equal on " \
        "every rank" in run.stdout, run.stdout
    assert "3 samples of 3 distinct scenes (reuse 1.00), 3 real images" in run.stdout, run.stdout
    assert "mixing 50 % real images from photos (4)" in run.stdout, run.stdout
    assert "eval at iteration 3 on testset (1 images): MIoU " in run.stdout, run.stdout
