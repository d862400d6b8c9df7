"""The design book: every citation of docs/design.md in the sources names one of its headings
(`docs/design.md, "Heading"` or `docs/design.md ("Heading"`), no source cites the founders' notes
by the bare name design.md, and the README's links into docs/ resolve.

CTest runs this file with Debian's /usr/bin/python3 -m pytest and STACKGEN_SOURCE_DIR set."""

import os
import re

from conftest import SOURCE

FOLDERS = ("types", "contract", "bus", "session", "cli", "gen", "consumers", "tools", "tests")
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


def test_readme_links_into_docs_resolve():
    with open(os.path.join(SOURCE, "README.md")) as file:
        links = re.findall(r"\]\((docs/[^)#\s]+)", file.read())
    assert links
    missing = [link for link in links if not os.path.exists(os.path.join(SOURCE, link))]
    assert not missing, missing
