"""tools/run as a user runs it (real processes, a bus of its own): a run stopped by SIGINT keeps
what it stored, says how to continue and exits 130; the printed command finishes it with the
same files as a run straight through; a run killed by SIGKILL leaves no process behind, and the
README's resume finishes it the same way (one with another --seed is refused, with no hint to
do the same again); a resume of a whole dataset says so and exits 0;
--split makes one dataset per split, disjoint by pile; bad arguments get one line before
anything is made.

CTest runs this file with Debian's /usr/bin/python3 -m pytest and STACKGEN_SOURCE_DIR set."""

import glob
import json
import os
import shlex
import signal
import subprocess
import time

import pytest

from conftest import SOURCE, TINY, descendants, left_running, quick_config

RUN = os.path.join(SOURCE, "tools", "run")


def run(*args):
    return subprocess.run([RUN, *args], capture_output=True, text=True, timeout=600)


def dataset_files(folder):
    """Relative path -> bytes of every file a COCO dataset holds (the contact sheet and the
    journal, whose records follow the groups the scenes arrived in, left out)."""
    files = {}
    for base, _, names in os.walk(folder):
        for name in names:
            if name in ("contact_sheet.png", "annotations.journal"):
                continue
            path = os.path.join(base, name)
            with open(path, "rb") as file:
                files[os.path.relpath(path, folder)] = file.read()
    return files


# a run of 12 scenes, stopped once it has stored 3 (each run starts a `stackgen --check` and a
# generator, which prepare the config's lighting environments first: the tiny config with one of
# them, conftest.quick_config)
COUNT = 12
ARGS = ["--config", TINY, "--count", str(COUNT), "--seed", "3"]


@pytest.fixture(scope="module", autouse=True)
def quick_tiny(tmp_path_factory):
    global ARGS
    ARGS = ["--config", quick_config(tmp_path_factory.mktemp("config")), "--count", str(COUNT),
            "--seed", "3"]
    yield ARGS


@pytest.fixture(scope="module")
def whole(tmp_path_factory):
    """The files of the run straight through."""
    out = tmp_path_factory.mktemp("run") / "whole"
    straight = run(*ARGS, "--out", str(out))
    assert straight.returncode == 0, straight.stderr
    assert "images: %d," % COUNT in straight.stdout
    return dataset_files(out)


def start_and_wait_for_images(cut, images_wanted=3, extra=()):
    """tools/run started on `cut` (with `extra` flags), once it has stored a few scenes."""
    process = subprocess.Popen([RUN, *ARGS, "--out", str(cut), *extra], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline:
        images = cut / "images"
        if images.is_dir() and len(os.listdir(images)) >= images_wanted:
            return process
        assert process.poll() is None, process.communicate()
        time.sleep(0.02)
    raise AssertionError("no %d images within 300 s" % images_wanted)


def test_interrupted_run_resumes_to_the_same_files(tmp_path, whole):
    cut = tmp_path / "cut"
    process = start_and_wait_for_images(cut)
    process.send_signal(signal.SIGINT)
    out, err = process.communicate(timeout=120)
    assert process.returncode == 130, err
    stored = len(os.listdir(cut / "images"))
    assert 3 <= stored < COUNT, err
    assert "tools/run: interrupted: %d of %d scenes stored in %s" % (stored, COUNT, cut) in err, \
        err
    hint = err.split("continue with:\n", 1)[1].strip()
    assert hint.startswith("tools/run --resume --out ")

    resumed = subprocess.run(shlex.split(hint), capture_output=True, text=True, timeout=600,
                             cwd=SOURCE)
    assert resumed.returncode == 0, resumed.stderr
    assert "%d in all" % COUNT in resumed.stdout, resumed.stdout
    assert dataset_files(cut) == whole


def test_killed_run_leaves_nothing_running_and_resumes(tmp_path, whole):
    # kill -9 of tools/run: its generator, writer, monitor and tee go with it (nothing finishes
    # the dataset behind the user's back, nothing holds its journal)
    cut = tmp_path / "cut"
    process = start_and_wait_for_images(cut, extra=("--monitor", "0"))
    children = descendants(process.pid)
    assert len(children) >= 3, children  # the writer, the generator and the monitor at least
    commands = []
    for child in children:
        try:
            with open("/proc/%d/cmdline" % child) as file:
                commands.append(file.read())
        except FileNotFoundError:
            pass
    assert any("stackgen-monitor" in command for command in commands), commands
    process.kill()
    process.communicate(timeout=60)
    assert not left_running(children)
    stored = len(os.listdir(cut / "images"))
    assert stored < COUNT
    # its temporary folder is left, and goes with the next run
    assert glob.glob("/tmp/stackgen-run.%d.*" % process.pid)

    # a resume with another seed is refused, and not told to do the same again
    wrong = run(*[("4" if arg == "3" else arg) for arg in ARGS], "--out", str(cut), "--resume")
    assert wrong.returncode == 1, wrong.stderr
    assert "holds scenes of another run" in wrong.stderr and "continue with" not in wrong.stderr
    assert len(os.listdir(cut / "images")) == stored

    # the README's resume: the same command with --resume
    resumed = run(*ARGS, "--out", str(cut), "--resume")
    assert resumed.returncode == 0, resumed.stderr
    assert "%d scenes made now, %d in all" % (COUNT - stored, COUNT) in resumed.stdout, \
        resumed.stdout
    assert dataset_files(cut) == whole
    assert not glob.glob("/tmp/stackgen-run.%d.*" % process.pid)

    # a resume of a whole dataset has nothing to make: it says so and exits 0
    again = run(*ARGS, "--out", str(cut), "--resume")
    assert again.returncode == 0, again.stderr
    assert "already holds its %d scenes: nothing to make" % COUNT in again.stdout, again.stdout
    assert dataset_files(cut) == whole


def test_split_is_disjoint_by_pile(tmp_path):
    out = tmp_path / "split"
    result = run("--config", ARGS[1], "--count", "10", "--split", "train=0.8,val=0.2", "--out",
                 str(out))
    assert result.returncode == 0, result.stderr
    splits = {}
    for name in ("train", "val"):
        with open(out / name / "annotations.json") as file:
            splits[name] = json.load(file)["images"]
    assert len(splits["train"]) == 8 and len(splits["val"]) == 2
    assert {image["stackgen"]["generator_id"] for image in splits["train"]} == {0}
    assert {image["stackgen"]["generator_id"] for image in splits["val"]} == {1}
    piles = [{image["stackgen"]["seed"] for image in images} for images in splits.values()]
    assert not piles[0] & piles[1]


def test_bad_arguments_make_nothing(tmp_path):
    out = tmp_path / "none"
    for args, text in [
            (["--count", "99999999999999999999"],
             "--count must be a whole number in 1..99,999,999"),
            (["--count", "0"], "--count must be"),
            (["--format", "yolo"], "--format must be coco, bop or both"),
            (["--split", "train=0.5,val=0.2"], "--split: the fractions add up to 0.7, not 1"),
            (["--split", "Train=1"], "--split: 'Train=1' is not NAME=FRACTION"),
            (["--resume"], "--resume: %s does not exist" % out),
            (["--monitor", "70000"], "--monitor must be a port in 0..65535")]:
        result = run(*args, "--out", str(out))
        assert result.returncode == 2, (args, result.stderr)
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and text in lines[0], (args, result.stderr)
        assert not out.exists()
