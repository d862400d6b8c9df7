"""The README's snippets, run as printed and offline (nothing downloaded). Python: against a real
generator of the tiny config on a bus of its own (given as $STACKGEN_LCM_URL, which they read),
the scene stream and the ten-line PyTorch loop followed by real photos mixed in and the scores of
its model on a COCO folder (made by stackgen-coco from the fixture log, the photos too); the
only changes are the counts (`count=100` and `count=1000` become 2, so that they end soon).
Shell: every ```sh block but the two commands (what CI runs), unchanged. Blocks of ```text are synopses, not run.

CTest runs this file with Debian's /usr/bin/python3 -m pytest; PYTHONPATH is the build's
python/ folder."""

import os
import re
import signal
import socket
import subprocess
import sys

from conftest import BIN, SOURCE, TINY, TINY_LOG


def snippet(after):
    """The first ```python block after the line `after` in the README."""
    with open(os.path.join(SOURCE, "README.md")) as file:
        text = file.read()
    start = text.index("\n" + after + "\n")
    return re.compile(r"```python\n(.*?)```", re.S).search(text, start).group(1)


def replaced(code, old, new):
    assert code.count(old) == 1, old
    return code.replace(old, new)


def run_with_generator(code, tmp_path):
    """Runs `code` in Debian's Python while a generator of the tiny config publishes until
    stopped (the code takes its scenes from whenever its stream joins); returns its stdout."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("", 0))
        url = "udpm://239.255.76.67:%d?ttl=0&recv_buf_size=4194304" % probe.getsockname()[1]
    env = dict(os.environ, STACKGEN_LCM_URL=url, OMP_WAIT_POLICY="PASSIVE",
               # no network: a download fails at once here
               http_proxy="http://0.0.0.0:9", https_proxy="http://0.0.0.0:9",
               TORCH_HOME=str(tmp_path / "torch"))
    (tmp_path / "snippet.py").write_text(code)
    generator = subprocess.Popen([os.path.join(BIN, "stackgen"), "--config", TINY, "--lcm-url",
                                  url, "--cache-dir", str(tmp_path / "cache")],
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        result = subprocess.run([sys.executable, str(tmp_path / "snippet.py")], env=env,
                                capture_output=True, text=True, timeout=600, cwd=tmp_path)
    finally:
        generator.send_signal(signal.SIGINT)
        generator_err = generator.communicate(timeout=60)[1]
    assert result.returncode == 0, result.stderr
    assert generator.returncode == 0, generator_err
    assert not os.path.exists(tmp_path / "torch"), "the snippet downloaded weights"
    return result.stdout


def test_scene_stream_runs_as_printed(tmp_path):
    code = replaced(snippet("### A scene stream"), "count=100", "count=2")
    out = run_with_generator(code + "\n        print('scene', scene.seq, len(scene.instances))\n",
                             tmp_path)
    assert len(re.findall(r"^scene \d+ 6$", out, re.M)) == 2, out


def test_ten_line_loop_and_its_scores_run_as_printed(tmp_path):
    made = subprocess.run([os.path.join(BIN, "stackgen-coco"), "--lcm-url",
                           "file://%s?speed=0" % TINY_LOG, "--open-bus", "--out",
                           str(tmp_path / "testset")], capture_output=True, text=True,
                          timeout=120)
    assert made.returncode == 0, made.stderr
    os.symlink("testset", tmp_path / "photos")
    loop = replaced(snippet("### A PyTorch dataset, in ten lines"), "count=1000", "count=2")
    mixed = replaced(snippet("Real photos and scores in the loop above (`tools.test_readme` runs "
                             "this after it, with a COCO\nfolder of the fixture scenes as both "
                             "folders):"), "count=1000", "count=2")
    scores = snippet("In Python, the same scores for any training loop (`tools.test_readme` runs "
                     "this after the\nten-line loop of [A PyTorch dataset]"
                     "(#a-pytorch-dataset-in-ten-lines), on a COCO folder of the\nfixture "
                     "scenes):")
    out = run_with_generator(loop + "print('loss', float(loss))\n" + mixed + scores, tmp_path)
    assert re.search(r"^loss \d+\.\d+", out, re.M), out
    # sgt.evaluate's scores, then DetectionScores' in a loop of one's own: the same (the first
    # has box AP too)
    results = re.findall(r"^\{'miou'.*\}$", out, re.M)
    assert len(results) == 2 and results[0].startswith(results[1][:-1] + ", 'box_ap': "), out
    assert "'images': 4" in results[0], out


def test_shell_snippets_run_as_printed(tmp_path):
    """Every ```sh block but the first (the two commands, tools/run and tools/test, are what CI
    runs on a clean clone) runs as printed with bash -e, in a folder that looks like the
    repository's root (tools, build, config, tests, consumers linked) so that its out/ and
    .venv/ are the test's."""
    with open(os.path.join(SOURCE, "README.md")) as file:
        blocks = re.findall(r"^```sh\n(.*?)^```", file.read(), re.S | re.M)
    assert len(blocks) >= 4
    root = tmp_path / "root"
    root.mkdir()
    for name in ("tools", "build", "config", "tests", "consumers"):
        os.symlink(os.path.join(SOURCE, name), root / name)
    # as a user's shell has it: the build's python/ folder only where a block says so
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    for block in blocks[1:]:
        result = subprocess.run(["bash", "-e", "-c", block], cwd=root, capture_output=True,
                                text=True, timeout=600, env=env)
        assert result.returncode == 0, (block, result.stdout[-2000:], result.stderr[-2000:])
        if ".venv/bin/python -c" in block:  # the venv's python imports the venv's package
            assert "/.venv/lib/python3" in result.stdout, result.stdout
    # what the blocks say they make
    assert (root / "out" / "yolo" / "data.yaml").is_file()
    assert (root / "stats2" / "cumulative.png").is_file()
    assert sorted(os.listdir(root / "out" / "job")) == ["task-00000", "task-00001"]
    assert len(os.listdir(root / "out" / "job-all" / "images")) == 8
    assert len(list((root / "out" / "deb").glob("stackgen_*_amd64.deb"))) == 1
    assert list((root / ".venv" / "lib").glob("python3*/site-packages/stackgen/_native.*.so"))
