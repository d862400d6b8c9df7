"""The folders' include rules (docs/design.md, "Layout"): each layer includes only the layers
below it, consumers never include gen/, only bus/ talks to LCM, and nothing but the tests
includes tests/, tools/ or research/ (the research bench's own files aside); and consumers read
time only through the clock seam.

CTest runs this file with Debian's /usr/bin/python3 -m pytest and STACKGEN_SOURCE_DIR set."""

import os
import re

from conftest import SOURCE

# what a file in each folder may include of the project's own, by first folder
ALLOWED = {
    "contract": {"contract"},
    "bus": {"contract", "bus"},
    "session": {"contract", "bus", "session"},
    "cli": {"contract", "bus", "cli"},
    "gen": {"contract", "bus", "session", "cli", "gen"},
    "consumers": {"contract", "bus", "session", "cli", "consumers"},
    "tools": {"contract", "bus", "session", "cli", "gen", "consumers", "tools"},
    "research": {"contract", "bus", "session", "cli", "gen", "consumers", "research"},
}
INCLUDE = re.compile(r'^\s*#\s*include\s+([<"])([^">]+)[">]', re.M)


def includes():
    """(file, line, included path, quoted) for every #include of the project's C++ sources."""
    for folder in ALLOWED:
        for base, _, names in os.walk(os.path.join(SOURCE, folder)):
            for name in names:
                if not name.endswith((".h", ".cc")):
                    continue
                path = os.path.join(base, name)
                with open(path) as file:
                    text = file.read()
                for match in INCLUDE.finditer(text):
                    line = text.count("\n", 0, match.start()) + 1
                    yield (os.path.relpath(path, SOURCE), line, match.group(2),
                           match.group(1) == '"')


def test_each_folder_includes_only_the_layers_below_it():
    found, wrong = 0, []
    for where, line, included, quoted in includes():
        if not quoted or "/" not in included:
            continue  # (a system header, or one generated beside the file: shaders.h, *.pb.h)
        found += 1
        folder, first = where.split(os.sep)[0], included.split("/")[0]
        if first not in ALLOWED[folder]:
            wrong.append("%s:%d includes %s" % (where, line, included))
    assert found > 200, found
    assert not wrong, "\n".join(wrong)


def test_only_bus_talks_to_lcm():
    # (generated message types include lcm/lcm_coretypes.h; bounded decoding reads it too)
    wrong = ["%s:%d includes <%s>" % (where, line, included)
             for where, line, included, quoted in includes()
             if not quoted and included.startswith("lcm/") and included != "lcm/lcm_coretypes.h"
             and not where.startswith("bus" + os.sep)]
    assert not wrong, "\n".join(wrong)


def test_consumers_read_time_through_the_clock_seam():
    # (bus/clock.h: SteadyClock() in programs, a ManualClock in tests)
    wrong = []
    for base, _, names in os.walk(os.path.join(SOURCE, "consumers")):
        for name in names:
            if name.endswith((".h", ".cc")):
                path = os.path.join(base, name)
                with open(path) as file:
                    for number, line in enumerate(file, 1):
                        if "steady_clock" in line or "system_clock" in line:
                            wrong.append("%s:%d" % (os.path.relpath(path, SOURCE), number))
    assert not wrong, wrong
