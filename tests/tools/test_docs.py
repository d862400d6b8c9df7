"""The documentation: every citation of docs/design.md in the sources names one of its headings
(`docs/design.md, "Heading"` or `docs/design.md ("Heading"`), no source cites the founders' notes
by the bare name design.md; every relative link of the README, the docs/ pages and
research/README.md resolves (files, and #anchors to headings of the markdown file linked, as
GitHub makes them); the README stays a front door (at most 260 lines); docs/programs.md gives
each program the flags its --help prints, and no other.

CTest runs this file with Debian's /usr/bin/python3 -m pytest and STACKGEN_SOURCE_DIR set."""

import os
import re
import subprocess

from conftest import BIN, SOURCE

FOLDERS = ("types", "contract", "bus", "session", "cli", "gen", "consumers", "tools", "tests", "research")
SUFFIXES = (".h", ".cc", ".py", ".proto", ".lcm", ".txt", ".sh", ".md")
CITATION = re.compile(r'docs/design\.md,?\s*(?://|#)?\s*\(?"([^"]+)"')


def headings():
    with open(os.path.join(SOURCE, "docs", "design.md")) as file:
        return {line[3:].strip() for line in file if line.startswith("## ")}


def sources():
    for folder in FOLDERS:
        for base, _, names in os.walk(os.path.join(SOURCE, folder)):
            for name in names:
                if name.endswith(SUFFIXES) or name == "CMakeLists.txt":
                    yield os.path.join(base, name)


def test_every_citation_names_a_heading_of_the_book():
    known = headings()
    assert {"Determinism", "Trust", "Delivery without loss", "Processes, nodes and time",
            "Layout"} <= known, known
    cited, bare = [], []
    for path in sources():
        with open(path, errors="replace") as file:
            text = file.read()
        where = os.path.relpath(path, SOURCE)
        if where == os.path.join("tests", "tools", "test_docs.py"):
            continue  # (its docstring shows the form)
        for match in re.finditer(r"design\.md", text):
            start = match.start()
            line = text.count("\n", 0, start) + 1
            if text[max(0, start - 5):start] != "docs/":
                bare.append("%s:%d" % (where, line))
                continue
            heading = CITATION.match(text, start - 5)
            if heading:
                cited.append((where, line, heading.group(1)))
    assert not bare, "cite the book as docs/design.md: %s" % bare
    assert len(cited) >= 10, cited
    unknown = ["%s:%d %r" % c for c in cited if c[2] not in known]
    assert not unknown, "no such heading in docs/design.md: %s" % unknown


PAGES = ["README.md", os.path.join("research", "README.md")] + sorted(
    os.path.join("docs", name) for name in os.listdir(os.path.join(SOURCE, "docs"))
    if name.endswith(".md"))


def slug(heading):
    """GitHub's anchor of a heading: lower case, punctuation but - and _ dropped, spaces as -."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def anchors(path):
    """The anchors of a markdown file's headings (outside code blocks); repeats get -1, -2, ..."""
    found, code = [], False
    with open(path) as file:
        for line in file:
            if line.startswith("```"):
                code = not code
            elif not code and re.match(r"#{1,6} ", line):
                base = slug(line.lstrip("#"))
                name, n = base, 0
                while name in found:
                    n += 1
                    name = "%s-%d" % (base, n)
                found.append(name)
    return set(found)


def links(page):
    """The relative links (and image sources) of a page, outside code blocks and code spans."""
    with open(os.path.join(SOURCE, page)) as file:
        text = re.sub(r"^```.*?^```", "", file.read(), flags=re.S | re.M)
    text = re.sub(r"`[^`]*`", "", text)
    return [target for target in re.findall(r"\]\(([^)\s]+)\)", text)
            if not re.match(r"[a-z]+:", target)]


def broken_links(page):
    broken = []
    for target in links(page):
        path, _, anchor = target.partition("#")
        linked = (os.path.normpath(os.path.join(SOURCE, os.path.dirname(page), path)) if path
                  else os.path.join(SOURCE, page))
        if not os.path.exists(linked):
            broken.append("%s: %s (no such file)" % (page, target))
        elif anchor and (not linked.endswith(".md") or anchor not in anchors(linked)):
            broken.append("%s: %s (no such heading)" % (page, target))
    return broken


def test_every_relative_link_resolves():
    assert {"README.md", os.path.join("docs", "programs.md"),
            os.path.join("research", "README.md")} <= set(PAGES), PAGES
    assert len(links("README.md")) >= 10
    broken = [line for page in PAGES for line in broken_links(page)]
    assert not broken, broken


def test_a_broken_link_is_found(tmp_path, monkeypatch):
    # the check itself: a missing file, a missing heading, a good link to a heading
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "a.md").write_text("# A page\n\n## The `tools/run` flags, in short\n")
    (tmp_path / "README.md").write_text(
        "[ok](docs/a.md#the-toolsrun-flags-in-short) [no file](docs/b.md) "
        "[no heading](docs/a.md#nothing) `[in code](docs/c.md)`\n")
    monkeypatch.setattr(__import__(__name__), "SOURCE", str(tmp_path))
    assert broken_links("README.md") == ["README.md: docs/b.md (no such file)",
                                         "README.md: docs/a.md#nothing (no such heading)"]


def test_the_readme_is_a_front_door():
    with open(os.path.join(SOURCE, "README.md")) as file:
        lines = file.read().splitlines()
    assert len(lines) <= 260, "README.md has %d lines: move the detail into docs/" % len(lines)
    assert "### A PyTorch dataset, in ten lines" in lines


# each section of docs/programs.md (its heading) and the command whose --help it documents
PROGRAMS = {
    "`stackgen`": [os.path.join(BIN, "stackgen")],
    "`stackgen-coco`": [os.path.join(BIN, "stackgen-coco")],
    "`stackgen-bop`": [os.path.join(BIN, "stackgen-bop")],
    "`tools/run`": [os.path.join(SOURCE, "tools", "run")],
    "`tools/task`": [os.path.join(SOURCE, "tools", "task")],
    "`stackgen-merge`": [os.path.join(BIN, "stackgen-merge")],
    "`tools/coco-to-yolo`": [os.path.join(SOURCE, "tools", "coco-to-yolo")],
    "`stackgen-view`": [os.path.join(BIN, "stackgen-view")],
    "`stackgen-overlay`": [os.path.join(BIN, "stackgen-overlay")],
    "`stackgen-monitor`": [os.path.join(BIN, "stackgen-monitor")],
    "Stock LCM tools: `tools/spy`, `tools/record`, replay": [os.path.join(SOURCE, "tools", "record")],
}
FLAG = re.compile(r"(?<![\w-])--[a-z][a-z0-9-]*")


def sections(path):
    """{heading: text} of the ## sections of a markdown file."""
    with open(path) as file:
        parts = re.split(r"^## (.*)\n", file.read(), flags=re.M)
    return dict(zip(parts[1::2], parts[2::2]))


def documented_flags(text, command):
    """The flags a section gives as its program's: those of its synopsis (a code block whose
    lines start with the command) and of the first column of its flag tables."""
    flags = set()
    for block in re.findall(r"^```\w*\n(.*?)^```", text, re.S | re.M):
        for line in block.splitlines():
            if line.startswith(command + " ") or line == command or line.startswith(" "):
                flags |= set(FLAG.findall(line.split("#")[0]))
    for row in re.findall(r"^\| (`--[^|]*)\|", text, re.M):
        flags |= set(FLAG.findall(row))
    return flags


def help_flags(argv):
    result = subprocess.run(argv + ["--help"], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, (argv, result.stderr)
    return set(FLAG.findall(result.stdout + result.stderr))


def programs_page_faults(page, known):
    faults = []
    found = sections(page)
    for heading, argv in PROGRAMS.items():
        if heading not in found:
            faults.append("no section %s" % heading)
            continue
        text = found[heading]
        command = heading.split("`")[1] if heading.startswith("`") else "tools/record"
        printed = known(argv)
        absent = sorted(flag for flag in printed if flag not in FLAG.findall(text))
        unknown = sorted(documented_flags(text, command) - printed)
        if absent:
            faults.append("%s: --help prints %s, the section does not" % (heading, absent))
        if unknown:
            faults.append("%s: the section gives %s, --help does not know them" % (heading, unknown))
    return faults


def test_programs_page_matches_every_help():
    page = os.path.join(SOURCE, "docs", "programs.md")
    faults = programs_page_faults(page, help_flags)
    assert not faults, faults


def test_a_dropped_or_unknown_flag_is_found(tmp_path):
    # the check itself, on a page whose stackgen-merge section lost --shards and gained --speed
    with open(os.path.join(SOURCE, "docs", "programs.md")) as file:
        text = file.read()
    merge = sections(os.path.join(SOURCE, "docs", "programs.md"))["`stackgen-merge`"]
    changed = merge.replace("--shards", "--speed")
    page = tmp_path / "programs.md"
    page.write_text(text.replace(merge, changed))
    faults = programs_page_faults(str(page), help_flags)
    assert faults == [
        "`stackgen-merge`: --help prints ['--shards'], the section does not",
        "`stackgen-merge`: the section gives ['--speed'], --help does not know them"], faults
