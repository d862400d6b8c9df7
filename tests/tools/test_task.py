"""tools/task and stackgen-merge as a cluster runs them (real processes, each task on buses of
its own): the shards of a job merge into the dataset one process makes of the same scenes, byte
for byte (COCO with webdataset shards, and BOP), however many tasks and generators made them; a
task killed with SIGKILL leaves no process behind and, run again, leaves the same shard; the index comes from
$JOB_COMPLETION_INDEX (Kubernetes) as from --task; the tasks' own webdataset shards stream into
stackgen.shards.ShardDataset without a merge; merge refuses a missing, repeated, foreign,
torn or busy shard with one line and writes nothing.

CTest runs this file with Debian's /usr/bin/python3 -m pytest, STACKGEN_SOURCE_DIR and
STACKGEN_BIN_DIR set."""

import fcntl
import os
import re
import shutil
import socket
import subprocess
import time

import pytest

from conftest import BIN, SOURCE, TINY, descendants, left_running, quick_config

TASK = os.path.join(SOURCE, "tools", "task")
MERGE = os.path.join(BIN, "stackgen-merge")
CONFIG = TINY  # the tasks' config: the tiny one with one lighting environment (fixture below)


@pytest.fixture(scope="module", autouse=True)
def quick_tiny(tmp_path_factory):
    """Every task and reference run of this file on conftest.quick_config: each task starts a
    `stackgen --check` and its generators, and each prepares the config's environments first."""
    global CONFIG
    CONFIG = quick_config(tmp_path_factory.mktemp("config"))
    yield CONFIG
    CONFIG = TINY


def task(out, count, tasks, *args, env=None):
    command = [TASK, "--out", str(out), "--count", str(count), "--tasks", str(tasks),
               "--config", CONFIG, *args]
    return subprocess.run(command, capture_output=True, text=True, timeout=600,
                          env={**os.environ, **(env or {})})


def merge(out, *inputs, shards=None):
    command = [MERGE, "--out", str(out)] + (["--shards", str(shards)] if shards else [])
    return subprocess.run(command + [str(path) for path in inputs], capture_output=True,
                          text=True, timeout=300)


def free_port():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("", 0))
        return probe.getsockname()[1]


def one_process(out, count, seed, fmt="coco", shards=None):
    """The reference: one generator making seqs 0..count-1 into one writer."""
    url = "udpm://239.255.76.67:%d?ttl=0&recv_buf_size=4194304" % free_port()
    writer = [os.path.join(BIN, "stackgen-" + fmt), "--out", str(out), "--count", str(count),
              "--lcm-url", url] + (["--shards", str(shards)] if shards else [])
    listening = subprocess.Popen(writer, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                 text=True)
    for line in listening.stdout:
        if "listening" in line:
            break
    generator = subprocess.run(
        [os.path.join(BIN, "stackgen"), "--config", CONFIG, "--count", str(count), "--seed",
         str(seed), "--lcm-url", url], capture_output=True, text=True, timeout=300)
    assert generator.returncode == 0, generator.stderr
    listening.stdout.read()
    assert listening.wait(timeout=60) == 0


def files_of(folder, leave_out=("annotations.journal", "bop.journal", "task.json")):
    """Relative path -> bytes of every file of a dataset (the journal, whose lines follow the
    order scenes arrived in, and the task record left out)."""
    files = {}
    for base, _, names in os.walk(folder):
        for name in names:
            if name in leave_out:
                continue
            path = os.path.join(base, name)
            with open(path, "rb") as file:
                files[os.path.relpath(path, folder)] = file.read()
    return files


@pytest.fixture(scope="module")
def job(tmp_path_factory):
    """A job of 10 scenes in 2 tasks (task 1 from Kubernetes' index, with 2 generators), with
    webdataset shards, and the same 10 scenes made by one process."""
    folder = tmp_path_factory.mktemp("job")
    first = task(folder / "shards", 10, 2, "--task", "0", "--generators", "1", "--seed", "2",
                 "--shards", "4")
    assert first.returncode == 0, first.stderr
    assert "task 0 of 2: seqs 0..4 of generator 0 (5 scenes), 1 generators" in first.stdout
    # (with a monitor on both its buses: it changes nothing of the shard)
    second = task(folder / "shards", 10, 2, "--generators", "2", "--seed", "2", "--shards", "4",
                  "--monitor", "0", env={"JOB_COMPLETION_INDEX": "1"})
    assert second.returncode == 0, second.stderr
    assert "task 1 of 2: seqs 5..9 of generator 0 (5 scenes), 2 generators" in second.stdout
    assert re.search(r"task 1: monitor at http://127\.0\.0\.1:\d+/ on ", second.stdout), \
        second.stdout
    one_process(folder / "one", 10, 2, shards=4)
    return folder


def test_shards_merge_to_the_one_process_dataset(job):
    shards = sorted((job / "shards").iterdir())
    assert [path.name for path in shards] == ["task-00000", "task-00001"]
    merged = merge(job / "merged", *shards, shards=4)
    assert merged.returncode == 0, merged.stderr
    assert "10 scenes of 2 inputs" in merged.stdout
    ours, reference = files_of(job / "merged"), files_of(job / "one")
    assert sorted(ours) == sorted(reference)
    assert len([name for name in ours if name.startswith("images/")]) == 10
    assert len([name for name in ours if name.startswith("shards/shard-")]) == 3
    for name in reference:
        assert ours[name] == reference[name], name
    # a learner streams the tasks' own webdataset shards, no merge needed: every image once
    from stackgen.shards import ShardDataset
    ids = [int(target["image_id"]) for _, target in ShardDataset([str(s) for s in shards])]
    assert sorted(ids) == list(range(1, 11))
    # a task run again when its shard is there does nothing
    again = task(job / "shards", 10, 2, "--task", "1", "--seed", "2", "--shards", "4")
    assert again.returncode == 0 and "done already" in again.stdout


def test_killed_task_runs_again_to_the_same_shard(tmp_path):
    clean = task(tmp_path / "clean", 16, 2, "--task", "0", "--generators", "1")
    assert clean.returncode == 0, clean.stderr
    out = tmp_path / "killed"
    process = subprocess.Popen(
        [TASK, "--out", str(out), "--count", "16", "--tasks", "2", "--task", "0", "--config",
         CONFIG, "--generators", "1"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    partial = out / ".task-00000.partial" / "part-000" / "images"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        if partial.is_dir() and len(os.listdir(partial)) >= 2:
            break
        assert process.poll() is None
        time.sleep(0.02)
    # the task script alone (a scheduler may kill only the job's first process): its
    # generator and writer go with it
    children = descendants(process.pid)
    assert len(children) >= 2, children
    process.kill()
    process.wait()
    assert not left_running(children)
    # killed half way: no shard at all, only the partial folder
    assert not (out / "task-00000").exists()
    assert 2 <= len(os.listdir(partial)) < 8
    again = task(out, 16, 2, "--task", "0", "--generators", "1")
    assert again.returncode == 0, again.stderr
    assert sorted(os.listdir(out)) == ["task-00000"]
    assert files_of(out / "task-00000", ()) == files_of(tmp_path / "clean" / "task-00000", ())


def test_bop_shards_merge_to_the_one_process_dataset(tmp_path):
    for index in ("0", "1"):
        made = task(tmp_path / "shards", 6, 2, "--task", index, "--format", "bop",
                    "--generators", "2")
        assert made.returncode == 0, made.stderr
    merged = merge(tmp_path / "merged", *sorted((tmp_path / "shards").iterdir()))
    assert merged.returncode == 0, merged.stderr
    one_process(tmp_path / "one", 6, 0, fmt="bop")
    ours, reference = files_of(tmp_path / "merged"), files_of(tmp_path / "one")
    assert sorted(ours) == sorted(reference)
    assert "train_pbr/000000/scene_gt.json" in ours
    for name in reference:
        assert ours[name] == reference[name], name


def refused(result, text):
    assert result.returncode == 1, result.stdout
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("stackgen-merge: error: "), result.stderr
    assert text in lines[0], lines[0]


def test_merge_refuses_bad_shards_with_one_line(job, tmp_path):
    shards = job / "shards"
    first, second = shards / "task-00000", shards / "task-00001"
    out = tmp_path / "out"
    refused(merge(out, first), "task 1 of 2 (seqs 5..9) is missing")
    copy = tmp_path / "copy"
    shutil.copytree(first, copy)
    refused(merge(out, first, copy, second), "task 0 of 2 is given twice")
    refused(merge(out, first, first, second), "given twice")
    foreign = task(tmp_path / "foreign", 10, 2, "--task", "1", "--seed", "3", "--shards", "4")
    assert foreign.returncode == 0, foreign.stderr
    refused(merge(out, first, tmp_path / "foreign" / "task-00001"), "is of another run (seed 3")
    torn = tmp_path / "torn"
    shutil.copytree(second, torn)
    with open(torn / "annotations.journal", "a") as journal:
        journal.write('{"image":{"file_na')
    refused(merge(out, first, torn), "ends in a torn record")
    # a writer still at work holds its journal's lock (a shared lock is enough to be refused)
    busy = tmp_path / "busy"
    shutil.copytree(second, busy)
    with open(busy / "annotations.journal", "rb") as journal:
        fcntl.flock(journal, fcntl.LOCK_EX | fcntl.LOCK_NB)
        refused(merge(out, first, busy), "busy: still being written")
    # one stopped before its annotations.json counts with what its journal holds
    stopped = tmp_path / "stopped"
    shutil.copytree(second, stopped)
    os.remove(stopped / "annotations.json")
    assert merge(tmp_path / "from-stopped", first, stopped, shards=4).returncode == 0
    assert files_of(tmp_path / "from-stopped") == files_of(job / "one")
    refused(merge(out, first, tmp_path / "nothing"), "no such folder")
    assert not out.exists() and not (tmp_path / "out.merging").exists()
    out.mkdir()
    (out / "x").write_text("mine")
    refused(merge(out, first, second), "is not an empty folder")


def test_task_refuses_bad_arguments_before_making_anything(tmp_path):
    out = tmp_path / "job"
    for args, text in [
        ([], "--tasks is required"),
        (["--tasks", "2", "--task", "2"], "task '2' is not one of 0..1"),
        (["--tasks", "20", "--task", "0"], "--tasks 20 is more than --count 10"),
        (["--tasks", "2", "--task", "0", "--format", "yolo"], "--format must be coco or bop"),
        (["--tasks", "2", "--task", "0", "--monitor", "x"], "--monitor must be a port"),
    ]:
        result = subprocess.run([TASK, "--out", str(out), "--count", "10", "--config", TINY,
                                 *args], capture_output=True, text=True, timeout=60,
                                env={k: v for k, v in os.environ.items()
                                     if not k.startswith(("SLURM_", "JOB_COMPLETION"))})
        assert result.returncode == 2, (args, result.stdout)
        assert result.stderr.startswith("tools/task: error: ") and text in result.stderr, \
            (args, result.stderr)
    bad_config = task(out, 10, 2, "--task", "0", "--config", str(tmp_path / "none.pbtxt"))
    assert bad_config.returncode == 1 and "stackgen: error: " in bad_config.stderr
    assert not out.exists()
