"""Real processes for the Python tests: free multicast URLs, programs with their output in files,
and the body of the `processes` fixture the conftest.py files declare."""

import socket
import subprocess
import time

import pytest


def free_url():
    """A multicast URL on this host only, on a port nothing is bound to."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("", 0))
        port = probe.getsockname()[1]
    return "udpm://239.255.76.67:%d?ttl=0&recv_buf_size=4194304" % port


class Process:
    """A program running as a real process, its output in files."""

    def __init__(self, argv, log_prefix):
        self.out_path = log_prefix + ".out"
        self.err_path = log_prefix + ".err"
        self._out = open(self.out_path, "w")
        self._err = open(self.err_path, "w")
        self.popen = subprocess.Popen([str(a) for a in argv], stdout=self._out, stderr=self._err)

    def wait(self, timeout):
        """The exit status; fails the test if it runs past `timeout` seconds."""
        try:
            return self.popen.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.popen.kill()
            self.popen.wait()
            pytest.fail("%s still ran after %g s; stderr: %s" % (
                self.popen.args[0], timeout, self.stderr()))

    def wait_for_output(self, text, timeout):
        """Whether `text` appears on its stdout within `timeout` seconds (or before it ends)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if text in self.stdout():
                return True
            if self.popen.poll() is not None:
                return text in self.stdout()
            time.sleep(0.02)
        return False

    def stdout(self):
        with open(self.out_path) as file:
            return file.read()

    def stderr(self):
        with open(self.err_path) as file:
            return file.read()

    def kill(self):
        if self.popen.poll() is None:
            self.popen.kill()
            self.popen.wait()
        self._out.close()
        self._err.close()


def started(tmp_path):
    """A `processes` fixture's body: yields start(argv, name), which runs a program with its
    output in tmp_path/name.out and .err, and kills those still running at the end."""
    running = []

    def start(argv, name):
        process = Process(argv, str(tmp_path / name))
        running.append(process)
        return process

    yield start
    for process in running:
        process.kill()
