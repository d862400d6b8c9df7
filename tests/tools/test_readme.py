"""The README's snippets, run as printed and offline (nothing downloaded). Python: against a real
generator of the tiny config on a bus of its own (given as $STACKGEN_LCM_URL, which they read),
the scene stream and the ten-line PyTorch loop, unchanged, each against a generator of a few
scenes started once the snippet listens: they end by themselves when its run ends, with a line
saying so (a hang fails the test); then real photos mixed in and the scores of the loop's model
on a COCO folder (made by stackgen-coco from the fixture log, the photos too), against a
generator that runs until stopped (`count=1000` becomes 2 there, so that it ends soon).
Shell: every ```sh block but the two commands (what CI runs), unchanged. Blocks of ```text are synopses, not run.

CTest runs this file with Debian's /usr/bin/python3 -m pytest; PYTHONPATH is the build's
python/ folder."""

import os
import re
import select
import signal
import socket
import subprocess
import sys
import time

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


def free_url():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("", 0))
        return "udpm://239.255.76.67:%d?ttl=0&recv_buf_size=4194304" % probe.getsockname()[1]


def snippet_env(url, tmp_path):
    return dict(os.environ, STACKGEN_LCM_URL=url, OMP_WAIT_POLICY="PASSIVE",
                # no network: a download fails at once here
                http_proxy="http://0.0.0.0:9", https_proxy="http://0.0.0.0:9",
                TORCH_HOME=str(tmp_path / "torch"))


def generator_command(url, tmp_path, *flags):
    return [os.path.join(BIN, "stackgen"), "--config", TINY, "--lcm-url", url, "--cache-dir",
            str(tmp_path / "cache"), *flags]


def read_until(pipe, pattern, seconds):
    """What the snippet writes on `pipe` up to the first line matching `pattern`."""
    text, end = "", time.monotonic() + seconds
    while not re.search(pattern, text, re.M):
        left = end - time.monotonic()
        assert left > 0, "no line %r within %d s: %s" % (pattern, seconds, text)
        if select.select([pipe], [], [], left)[0]:
            # (the descriptor itself: nothing waits unseen in a file object's buffer, and
            # communicate() later reads the rest)
            chunk = os.read(pipe.fileno(), 65536)
            assert chunk, "the snippet ended: %s" % text
            text += chunk.decode()
    return text


# what a stream that waits and has heard nothing says (within seconds), and the snippets' cue to
# start their generator
WAITING = r"^stackgen-feed: waiting for scenes on STACKGEN_SCENE: no generator heard on udpm://"


def run_with_generator(code, tmp_path):
    """Runs `code` in Debian's Python while a generator of the tiny config publishes until
    stopped (the code takes its scenes from whenever its stream joins); returns its stdout."""
    url = free_url()
    env = snippet_env(url, tmp_path)
    (tmp_path / "snippet.py").write_text(code)
    generator = subprocess.Popen(generator_command(url, tmp_path),
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


def test_scene_stream_runs_as_printed_and_ends_with_the_run(tmp_path):
    # as printed (count=100): a generator of 3 scenes, started once the stream listens, ends
    # the loop by its end
    url = free_url()
    code = snippet("### A scene stream") + "        print('scene', scene.seq, len(scene.instances))\n"
    (tmp_path / "snippet.py").write_text(code + "print('the loop ended')\n")
    learner = subprocess.Popen([sys.executable, str(tmp_path / "snippet.py")],
                               env=snippet_env(url, tmp_path), stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    try:
        waiting = read_until(learner.stderr, WAITING, 120)
        generator = subprocess.run(generator_command(url, tmp_path, "--count", "3"),
                                   capture_output=True, text=True, timeout=120)
        assert generator.returncode == 0, generator.stderr
        out, err = learner.communicate(timeout=30)  # a hang fails here
        err = waiting + err
    finally:
        learner.kill()
    assert learner.returncode == 0, err
    assert len(re.findall(r"^scene \d+ 6$", out, re.M)) == 3 and "the loop ended" in out, out
    assert "generator 0 ended its run (3 scenes published): the stream ends after the 3 " in err


def test_ten_line_loop_and_its_scores_run_as_printed(tmp_path):
    made = subprocess.run([os.path.join(BIN, "stackgen-coco"), "--lcm-url",
                           "file://%s?speed=0" % TINY_LOG, "--open-bus", "--out",
                           str(tmp_path / "testset")], capture_output=True, text=True,
                          timeout=120)
    assert made.returncode == 0, made.stderr
    os.symlink("testset", tmp_path / "photos")
    loop = snippet("### A PyTorch dataset, in ten lines")
    mixed = replaced(snippet("Real photos and scores in the loop above (`tools.test_readme` runs "
                             "this after it, with a COCO\nfolder of the fixture scenes as both "
                             "folders):"), "count=1000", "count=2")
    scores = snippet("In Python, the same scores for any training loop (`tools.test_readme` runs "
                     "this after the\nten-line loop of [A PyTorch dataset]"
                     "(#a-pytorch-dataset-in-ten-lines), on a COCO folder of the\nfixture "
                     "scenes):")
    # the loop as printed (count=1000) against a generator of 2 scenes: it ends with that run;
    # then, once told, the rest against a generator that runs until stopped
    url = free_url()
    (tmp_path / "snippet.py").write_text(loop + "print('loss', float(loss), flush=True)\n" +
                                         "input()\n" + mixed + scores)
    learner = subprocess.Popen([sys.executable, str(tmp_path / "snippet.py")],
                               env=snippet_env(url, tmp_path), stdin=subprocess.PIPE,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               cwd=tmp_path)
    generator = None
    try:
        read_until(learner.stderr, WAITING, 300)
        counted = subprocess.run(generator_command(url, tmp_path, "--count", "2"),
                                 capture_output=True, text=True, timeout=300)
        assert counted.returncode == 0, counted.stderr
        out = read_until(learner.stdout, r"^loss \d+\.\d+", 300)  # a hang fails here
        generator = subprocess.Popen(generator_command(url, tmp_path), stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True)
        rest, err = learner.communicate("\n", timeout=600)
        out += rest
    finally:
        learner.kill()
        if generator is not None:
            generator.send_signal(signal.SIGINT)
            generator.communicate(timeout=60)
    assert learner.returncode == 0, err
    assert "generator 0 ended its run (2 scenes published): the stream ends after the 2 " in err
    assert not os.path.exists(tmp_path / "torch"), "the snippet downloaded weights"
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
