"""The build step of `pip install ./consumers/feed` (pyproject.toml says why setuptools).

Configures the whole stackgen CMake project (the repository root, two folders up) for the
interpreter that runs pip, builds the target stackgen_python (the native module stackgen._native,
the lcm-gen message types and the package's Python files, assembled in BUILD/python/stackgen) and
puts that folder into the wheel. The CMake build folder is $STACKGEN_CMAKE_BUILD_DIR when set (an
existing one is built incrementally), else build-pip/ at the repository root; setuptools' own
scratch goes there too, so the source tree stays clean. The version is the CMake project's.
"""

import os
import re
import shutil
import subprocess
import sysconfig
import sys

from setuptools import setup
from setuptools.command.build_py import build_py
from setuptools.dist import Distribution

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
CMAKE_BUILD = os.path.abspath(os.environ.get("STACKGEN_CMAKE_BUILD_DIR") or
                              os.path.join(ROOT, "build-pip"))
SCRATCH = os.path.join(CMAKE_BUILD, "python-setup")


def project_version():
    with open(os.path.join(ROOT, "CMakeLists.txt")) as cmake_lists:
        match = re.search(r"project\(stackgen VERSION ([0-9.]+)", cmake_lists.read())
    if not match:
        sys.exit("setup.py: %s/CMakeLists.txt names no project version" % ROOT)
    return match.group(1)


def run(command):
    print("stackgen: " + " ".join(command), flush=True)
    subprocess.run(command, check=True)


class CMakeBuildPy(build_py):
    """build_py that builds the package with CMake and copies it whole into the wheel."""

    def run(self):
        if not os.path.exists(os.path.join(CMAKE_BUILD, "CMakeCache.txt")):
            run(["cmake", "-S", ROOT, "-B", CMAKE_BUILD, "-DCMAKE_BUILD_TYPE=Release",
                 "-DPython_EXECUTABLE=" + sys.executable])
        jobs = os.environ.get("CMAKE_BUILD_PARALLEL_LEVEL") or str(os.cpu_count() or 2)
        run(["cmake", "--build", CMAKE_BUILD, "--target", "stackgen_python", "-j", jobs])
        built = os.path.join(CMAKE_BUILD, "python", "stackgen")
        suffix = sysconfig.get_config_var("EXT_SUFFIX")
        if not os.path.exists(os.path.join(built, "_native" + suffix)):
            sys.exit("setup.py: %s has no _native%s: the CMake build folder %s was configured for "
                     "another Python than %s (remove it, or set STACKGEN_CMAKE_BUILD_DIR)" %
                     (built, suffix, CMAKE_BUILD, sys.executable))
        target = os.path.join(self.build_lib, "stackgen")
        if os.path.exists(target):
            shutil.rmtree(target)
        shutil.copytree(built, target, ignore=shutil.ignore_patterns("__pycache__"))


class NativeDistribution(Distribution):
    """A wheel for this platform and interpreter: the package holds a native module."""

    def has_ext_modules(self):
        return True


os.makedirs(SCRATCH, exist_ok=True)
setup(
    version=project_version(),
    packages=["stackgen"],
    package_dir={"stackgen": "stackgen"},
    distclass=NativeDistribution,
    cmdclass={"build_py": CMakeBuildPy},
    options={"build": {"build_base": SCRATCH}, "egg_info": {"egg_base": SCRATCH}},
    zip_safe=False,
)
