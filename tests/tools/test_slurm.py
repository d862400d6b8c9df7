"""A cluster job on real Slurm (22.05, Debian's): a private one-node cluster on this machine
(slurm_cluster.py: its own munged, slurmctld and slurmd), `sbatch --array=0-3` of the shipped
tools/deploy/slurm-array.sbatch (tools/task),
one task killed with SIGKILL half way (its whole process tree, as a lost node would) and
requeued with `scontrol requeue`; the four shards then merge into the dataset one process makes
of the same scenes, byte for byte.

CTest runs this file with Debian's /usr/bin/python3 -m pytest, STACKGEN_SOURCE_DIR and
STACKGEN_BIN_DIR set. It needs root (slurmd runs job steps as root) and tools/install-deps
--slurm; without either it is skipped, saying which."""

import os
import re
import signal
import time

import pytest

from conftest import SOURCE, TINY
from slurm_cluster import local_slurm, why_not_available
from test_task import files_of, merge, one_process


def task_processes(job_id, index):
    """Pids of every process of array task `index` of `job_id` (tools/task, its generators and
    writers inherit the task's environment)."""
    wanted = {b"SLURM_ARRAY_JOB_ID=" + job_id.encode(),
              b"SLURM_ARRAY_TASK_ID=" + str(index).encode()}
    pids = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open("/proc/%s/environ" % entry, "rb") as file:
                environ = set(file.read().split(b"\0"))
        except OSError:
            continue
        if wanted <= environ:
            pids.append(int(entry))
    return pids


def test_array_job_with_a_killed_task_merges_to_one_process(tmp_path):
    reason = why_not_available()
    if reason:
        pytest.skip(reason)
    out = tmp_path / "job"
    with local_slurm(tmp_path / "slurm", requeue_delay_s=5) as cluster:
        # the shipped script, its settings in the environment as its comment says
        job = cluster.sbatch([
            "--array=0-3", "--cpus-per-task=1", "-D", str(tmp_path), "--open-mode=append",
            "-o", str(tmp_path / "task-%a.log"),
            "--export=ALL,OUT=%s,COUNT=40,CONFIG=%s,STACKGEN_ROOT=%s,MONITOR=0"
            % (out, TINY, SOURCE),
            os.path.join(SOURCE, "tools", "deploy", "slurm-array.sbatch")])
        # task 2 half way: some scenes stored, the shard not there
        images = out / ".task-00002.partial" / "part-000" / "images"
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline:
            if images.is_dir() and len(os.listdir(images)) >= 2:
                break
            assert cluster.states(job).get(2) in (None, "PENDING", "RUNNING"), cluster.states(job)
            time.sleep(0.02)
        pids = task_processes(job, 2)
        assert len(pids) >= 3, pids  # tools/task, a generator and a writer at least
        for pid in pids:
            os.kill(pid, signal.SIGKILL)
        stored = len(os.listdir(images))
        assert 2 <= stored < 10 and not (out / "task-00002").exists()
        # the scheduler sees it fail; then it is requeued
        deadline = time.monotonic() + 60
        while cluster.states(job).get(2) not in ("FAILED", "COMPLETED") and \
                time.monotonic() < deadline:
            time.sleep(0.1)
        assert cluster.states(job).get(2) == "FAILED", cluster.states(job)
        requeued = cluster.client("scontrol", "requeue", "%s_2" % job)
        assert requeued.returncode == 0, requeued.stderr
        # (it starts again once slurmd forgets the killed run: the credential's 5 s, and 1)
        cluster.wait(job, timeout=300)
    logs = {index: (tmp_path / ("task-%d.log" % index)).read_text() for index in range(4)}
    for index, log in logs.items():
        assert "tools/task: task %d of 4 done: 10 scenes" % index in log, log
        # each with its monitor on every address of the node (MONITOR=0: a free port)
        assert re.search(r"task %d: monitor at http://0\.0\.0\.0:\d+/ on " % index, log), log
    # task 2 ran twice: killed, then to its end from what its writer had stored
    assert logs[2].count("tools/task: task 2 of 4: seqs 20..29") == 2, logs[2]
    assert sorted(os.listdir(out)) == ["task-%05d" % index for index in range(4)]

    merged = merge(tmp_path / "merged", *sorted(out.iterdir()))
    assert merged.returncode == 0, merged.stderr
    one_process(tmp_path / "one", 40, 0)
    ours, reference = files_of(tmp_path / "merged"), files_of(tmp_path / "one")
    assert sorted(ours) == sorted(reference) and len(ours) == 41
    for name in reference:
        assert ours[name] == reference[name], name
