"""The README's ten-line PyTorch loop, run as printed: offline (nothing downloaded), against a
real generator of the tiny config on a bus of its own (given as $STACKGEN_LCM_URL, which the
loop reads), with the one change that `count=1000` becomes `count=2` so that it ends after one
step.

CTest runs this file with Debian's /usr/bin/python3 -m pytest; PYTHONPATH is the build's
python/ folder."""

import os
import re
import signal
import socket
import subprocess
import sys

SOURCE = os.environ.get("STACKGEN_SOURCE_DIR",
                        os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(
                            __file__)))))
BIN = os.environ.get("STACKGEN_BIN_DIR", os.path.join(SOURCE, "build", "bin"))
TINY = os.path.join(SOURCE, "tests", "fixtures", "logs", "tiny.pbtxt")


def snippet(heading):
    """The first ```python block after `heading` in the README."""
    with open(os.path.join(SOURCE, "README.md")) as file:
        text = file.read()
    start = text.index("\n" + heading + "\n")
    match = re.compile(r"```python\n(.*?)```", re.S).search(text, start)
    return match.group(1)


def test_ten_line_loop_runs_as_printed(tmp_path):
    code = snippet("### A PyTorch dataset, in ten lines")
    assert code.count("count=1000") == 1
    code = code.replace("count=1000", "count=2") + "\nprint('loss', float(loss))\n"
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("", 0))
        url = "udpm://239.255.76.67:%d?ttl=0&recv_buf_size=4194304" % probe.getsockname()[1]
    env = dict(os.environ, STACKGEN_LCM_URL=url, OMP_WAIT_POLICY="PASSIVE",
               # no network: a download would fail here, not hang
               http_proxy="http://0.0.0.0:9", https_proxy="http://0.0.0.0:9",
               TORCH_HOME=str(tmp_path / "torch"))
    (tmp_path / "loop.py").write_text(code)
    # a generator that runs until stopped: the loop takes its first two scenes from whenever
    # its stream joins (after the model is built)
    generator = subprocess.Popen([os.path.join(BIN, "stackgen"), "--config", TINY, "--lcm-url",
                                  url, "--cache-dir", str(tmp_path / "cache")],
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        learner = subprocess.run([sys.executable, str(tmp_path / "loop.py")], env=env,
                                 capture_output=True, text=True, timeout=600)
    finally:
        generator.send_signal(signal.SIGINT)
        generator_err = generator.communicate(timeout=60)[1]
    assert learner.returncode == 0, learner.stderr
    assert generator.returncode == 0, generator_err
    out = learner.stdout
    assert re.search(r"^loss \d+\.\d+", out, re.M), out
    assert not os.path.exists(tmp_path / "torch"), "the loop downloaded weights"
