"""The snippets of the README, the docs/ pages and research/README.md, run as printed and offline
(nothing downloaded). Python: against a real
generator of the tiny config on a bus of its own (given as $STACKGEN_LCM_URL, which they read),
the scene stream and the ten-line PyTorch loop, unchanged, each against a generator of a few
scenes started once the snippet listens: they end by themselves when its run ends, with a line
saying so (a hang fails the test); then real photos mixed in and the scores of the loop's model
on a COCO folder (made by stackgen-coco from the first 2 scenes of the fixture log, the photos
too), against a generator that runs until stopped (`count=1000` becomes 1 there, so that it ends
soon: one step, a photo and a scene). A Mask R-CNN step on the CPU costs 10-20 s and an image
scored 2-3 s, so the test takes as few as show that the code runs as printed.
Shell: every ```sh block but the README's first (the two commands: what CI runs), unchanged.
Blocks of ```text are synopses or commands another test runs (said below), not run here.

CTest runs this file with Debian's /usr/bin/python3 -m pytest; PYTHONPATH is the build's
python/ folder."""

import os
import re
import select
import socket
import subprocess
import sys
import time

from conftest import BIN, SOURCE, TINY, TINY_LOG


# the pages whose ```sh blocks run, in this order (a block may use what one before it made)
PAGES = ["README.md"] + sorted(os.path.join("docs", name) for name in
                               os.listdir(os.path.join(SOURCE, "docs")) if name.endswith(".md")) + [
                                   os.path.join("research", "README.md")]


def snippet(page, after):
    """The first ```python block after the text `after` in `page` (a path from the source root)."""
    with open(os.path.join(SOURCE, page)) as file:
        text = file.read()
    start = text.index(after)
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


def test_scene_stream_runs_as_printed_and_ends_with_the_run(tmp_path):
    # as printed (count=100): a generator of 3 scenes, started once the stream listens, ends
    # the loop by its end
    url = free_url()
    code = snippet("docs/training.md", "\n## A scene stream\n") + "        print('scene', scene.seq, len(scene.instances))\n"
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
                           "file://%s?speed=0" % TINY_LOG, "--open-bus", "--count", "2", "--out",
                           str(tmp_path / "testset")], capture_output=True, text=True,
                          timeout=120)
    assert made.returncode == 0, made.stderr
    os.symlink("testset", tmp_path / "photos")
    loop = snippet("README.md", "\n### A PyTorch dataset, in ten lines\n")
    mixed = replaced(snippet("docs/training.md", "Real photos and scores in the README's loop"),
                     "count=1000", "count=1")
    scores = snippet("docs/training.md", "In Python, the same scores for any training loop")
    # the loop as printed (count=1000) against a generator of 2 scenes: it ends with that run;
    # then, once told, photos and scores, against a generator of 1 scene started once the mixed
    # stream listens (so that no generator runs beside the scoring)
    url = free_url()
    (tmp_path / "snippet.py").write_text(loop + "print('loss', float(loss), flush=True)\n" +
                                         "input()\n" + mixed + scores)
    learner = subprocess.Popen([sys.executable, str(tmp_path / "snippet.py")],
                               env=snippet_env(url, tmp_path), stdin=subprocess.PIPE,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               cwd=tmp_path)
    started = time.monotonic()
    try:
        read_until(learner.stderr, WAITING, 300)
        counted = subprocess.run(generator_command(url, tmp_path, "--count", "2"),
                                 capture_output=True, text=True, timeout=300)
        assert counted.returncode == 0, counted.stderr
        out = read_until(learner.stdout, r"^loss \d+\.\d+", 300)  # a hang fails here
        print("the ten-line loop: %.1f s" % (time.monotonic() - started))
        learner.stdin.write("\n")
        learner.stdin.flush()
        err = read_until(learner.stderr, WAITING, 300)  # the first stream's end, then the second's wait
        second = subprocess.run(generator_command(url, tmp_path, "--count", "1"),
                                capture_output=True, text=True, timeout=300)
        assert second.returncode == 0, second.stderr
        rest, more = learner.communicate(timeout=600)
        print("then photos and scores: %.1f s" % (time.monotonic() - started))
        out += rest
        err += more
    finally:
        learner.kill()
    assert learner.returncode == 0, err
    assert "generator 0 ended its run (2 scenes published): the stream ends after the 2 " in err
    assert "generator 0 ended its run (1 scenes published): the stream ends after the 1 " in err
    assert not os.path.exists(tmp_path / "torch"), "the snippet downloaded weights"
    # sgt.evaluate's scores, then DetectionScores' in a loop of one's own: the same (the first
    # has box AP too)
    results = re.findall(r"^\{'miou'.*\}$", out, re.M)
    assert len(results) == 2 and results[0].startswith(results[1][:-1] + ", 'box_ap': "), out
    assert "'images': 2" in results[0], out


def shell_blocks():
    """(page, block) for every ```sh block of the pages but the README's first (the two commands,
    tools/run and tools/test, are what CI runs on a clean clone). Blocks of ```text are synopses
    or commands another test runs (said beside each below), not run here."""
    blocks = []
    for page in PAGES:
        with open(os.path.join(SOURCE, page)) as file:
            found = re.findall(r"^```sh\n(.*?)^```", file.read(), re.S | re.M)
        blocks += [(page, block) for block in (found[1:] if page == "README.md" else found)]
    return blocks


# Commands of the pages written as ```text because another test runs them (the same command),
# so this test does not pay for them twice:
# - docs/install.md, the .deb: feed.test_install (tests/consumers/feed/test_install.py,
#   test_debian_package_unpacked_runs) runs cpack in the build folder, which is what
#   tools/package runs after tools/install-deps and the build, and checks the package.
# - docs/install.md, pip into a venv: feed.test_install (test_pip_install_into_a_fresh_venv_streams)
#   runs the same three commands (venv --system-site-packages; pip install --no-build-isolation
#   with STACKGEN_CMAKE_BUILD_DIR at the build folder; the venv's python imports the venv's
#   package) and streams scenes with it.
# - docs/developers.md: developer notes (lcm-spy's launcher, xvfb, a replay by hand, a
#   stackgen-stats comparison of 400 scenes, a pytest file that CTest runs as feed.test_augment).
def test_shell_snippets_run_as_printed(tmp_path):
    """Every ```sh block runs as printed with bash -e, in a folder that looks like the
    repository's root (tools, build, config, tests, consumers, research, docs linked) so that its
    out/ is the test's."""
    blocks = shell_blocks()
    assert len(blocks) >= 4, blocks
    root = tmp_path / "root"
    root.mkdir()
    for name in ("tools", "build", "config", "tests", "consumers", "research", "docs"):
        os.symlink(os.path.join(SOURCE, name), root / name)
    # as a user's shell has it: the build's python/ folder only where a block says so
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    for page, block in blocks:
        start = time.monotonic()
        result = subprocess.run(["bash", "-e", "-c", block], cwd=root, capture_output=True,
                                text=True, timeout=600, env=env)
        print("%s: %.1f s: %s" % (page, time.monotonic() - start, block.splitlines()[0]))
        assert result.returncode == 0, (page, block, result.stdout[-2000:], result.stderr[-2000:])
    # what the blocks say they make
    assert (root / "out" / "yolo" / "data.yaml").is_file()
    assert (root / "stats2" / "cumulative.png").is_file()
    assert sorted(os.listdir(root / "out" / "job")) == ["task-00000", "task-00001"]
    assert len(os.listdir(root / "out" / "job-all" / "images")) == 8
