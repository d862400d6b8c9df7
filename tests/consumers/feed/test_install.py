"""stackgen installed the two ways the README's "Install" gives, and used from outside the source
tree: `pip install ./consumers/feed` into a fresh virtual environment (Debian's setuptools, no
network), and the Debian package that tools/package makes (CPack), unpacked into a scratch root
with `dpkg-deb -x` (installing it for real needs root and changes the machine)."""

import glob
import json
import os
import re
import subprocess

from conftest import BIN, SOURCE, TINY_LOG, free_url, generator_argv

BUILD = os.path.dirname(BIN)

# opens a reliable stream on the URL, says so, and prints where stackgen came from and the
# scenes it got
STREAM = """
import sys
import stackgen
with stackgen.Stream(sys.argv[1], reliable=True, count=3, timeout=60) as stream:
    print("listening", flush=True)
    seqs = [scene.seq for scene in stream]
print(stackgen.__file__)
print(seqs)
"""


def environment(**extra):
    """The test's environment without the build's python/ folder on PYTHONPATH."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env.update(extra)
    return env


def run(argv, **kwargs):
    result = subprocess.run([str(a) for a in argv], capture_output=True, text=True, timeout=600,
                            **kwargs)
    assert result.returncode == 0, "%s: %s%s" % (argv[0], result.stdout, result.stderr)
    return result


# pip builds the package with its CMake step and installs it into a fresh venv; from another
# folder the venv's python imports it from the venv and streams a live generator's scenes
def test_pip_install_into_a_fresh_venv_streams(tmp_path, processes):
    venv = tmp_path / "venv"
    run(["/usr/bin/python3", "-m", "venv", "--system-site-packages", venv])
    python = venv / "bin" / "python"
    # the build folder of this test run: setup.py builds it incrementally (nothing left to do
    # after tools/test's build); without STACKGEN_CMAKE_BUILD_DIR it configures build-pip/
    run([python, "-m", "pip", "install", "--no-build-isolation", "--no-index",
         os.path.join(SOURCE, "consumers", "feed")],
        env=environment(STACKGEN_CMAKE_BUILD_DIR=BUILD))
    installed = glob.glob(str(venv / "lib" / "python3*" / "site-packages" / "stackgen" /
                              "_native.*.so"))
    assert len(installed) == 1

    url = free_url()
    with open(tmp_path / "stream.out", "w") as out:
        learner = subprocess.Popen([str(python), "-c", STREAM, url], cwd=tmp_path, stdout=out,
                                   stderr=subprocess.PIPE, text=True, env=environment())
        try:
            deadline = 30
            while "listening" not in (tmp_path / "stream.out").read_text() and deadline > 0:
                assert learner.poll() is None, learner.stderr.read()
                subprocess.run(["sleep", "0.1"])
                deadline -= 0.1
            generator = processes(generator_argv(url, 3, tmp_path / "cache"), "stackgen")
            assert learner.wait(timeout=90) == 0, learner.stderr.read()
        finally:
            if learner.poll() is None:
                learner.kill()
                learner.wait()
    assert generator.wait(60) == 0, generator.stderr()
    lines = (tmp_path / "stream.out").read_text().splitlines()
    assert lines[1] == os.path.join(os.path.dirname(installed[0]), "__init__.py")
    assert lines[2] == "[0, 1, 2]"


# every program and script the README's user sections use, as the .deb names them
PACKAGED = ["stackgen", "stackgen-coco", "stackgen-bop", "stackgen-view", "stackgen-stats",
            "stackgen-overlay", "stackgen-rest-check", "stackgen-record", "stackgen-merge",
            "stackgen-run", "stackgen-task", "stackgen-coco-to-yolo", "stackgen-train-live"]


# the .deb holds the programs and the user's scripts, the configs, the package, a copyright
# file and a changelog, with the libraries they link as dependencies, and lintian finds no
# error in it; unpacked, its stackgen-run (tools/run) makes a dataset with the package's own
# programs and default config (and that config its part), and Debian's python3 imports its
# package
def test_debian_package_unpacked_runs(tmp_path):
    run(["cpack", "-B", tmp_path / "package"], cwd=BUILD)
    debs = glob.glob(str(tmp_path / "package" / "stackgen_*_amd64.deb"))
    assert len(debs) == 1
    depends = run(["dpkg-deb", "-f", debs[0], "Depends"]).stdout
    for package in ("liblcm1", "libbullet3.24", "libassimp5", "python3-numpy", "libegl-mesa0"):
        assert package in depends, depends
    listed = run(["dpkg-deb", "-c", debs[0]]).stdout
    for program in PACKAGED:
        assert re.search(r" \./usr/bin/%s( -> |$)" % re.escape(program), listed, re.M), program
    for doc in ("copyright", "changelog.gz"):
        assert "./usr/share/doc/stackgen/%s\n" % doc in listed, doc
    # (lintian prints E: for an error, W: for a warning, I: for information)
    checked = subprocess.run(["lintian", "--no-tag-display-limit", debs[0]],
                             capture_output=True, text=True, timeout=600)
    errors = [line for line in checked.stdout.splitlines() if line.startswith("E: ")]
    assert not errors and "E: " not in checked.stderr, checked.stdout + checked.stderr

    root = tmp_path / "root"
    run(["dpkg-deb", "-x", debs[0], root])
    usr = root / "usr"
    default_config = usr / "share" / "stackgen" / "config" / "default.pbtxt"
    assert "(default: %s)" % default_config in run([usr / "bin" / "stackgen", "--help"]).stdout
    made = run([usr / "bin" / "stackgen-run", "--count", 2, "--out", tmp_path / "coco"],
               cwd=tmp_path, env=environment(XDG_CACHE_HOME=str(tmp_path / "cache")))
    # nothing built: the package's programs, and its default config
    assert "stackgen: build" not in made.stderr, made.stderr
    assert "config %s" % default_config in made.stdout + made.stderr, made.stdout
    assert "images: 2, annotations: " in made.stdout, made.stdout
    with open(tmp_path / "coco" / "annotations.json") as file:
        dataset = json.load(file)
    assert len(dataset["images"]) == 2 and len(dataset["annotations"]) > 0

    python_dir = usr / "lib" / "python3" / "dist-packages"
    imported = run(["/usr/bin/python3", "-c",
                    "import stackgen, sys\n"
                    "print(stackgen.__file__)\n"
                    "print(len(list(stackgen.Stream(sys.argv[1], open_bus=True))))",
                    "file://" + TINY_LOG],
                   cwd=tmp_path, env=environment(PYTHONPATH=str(python_dir))).stdout.split()
    assert imported == [str(python_dir / "stackgen" / "__init__.py"), "4"]
