"""stackgen/_native.pyi names what the native module has, no more and no less: every public
function, constant and class, and every public attribute of each class (those the package adds
to Scene included), so editors and type checkers see the real API."""

import ast
import os

import stackgen
from stackgen import _native

STUB = os.path.join(os.path.dirname(stackgen.__file__), "_native.pyi")


def stub_names():
    with open(STUB) as file:
        tree = ast.parse(file.read())
    top, members = set(), {}
    for node in tree.body:
        if isinstance(node, ast.ClassDef):
            top.add(node.name)
            names = set()
            for item in node.body:
                if isinstance(item, ast.FunctionDef):
                    names.add(item.name)
                elif isinstance(item, ast.AnnAssign):
                    names.add(item.target.id)
            members[node.name] = {n for n in names if not n.startswith("_")}
        elif isinstance(node, ast.FunctionDef):
            top.add(node.name)
        elif isinstance(node, ast.AnnAssign):
            top.add(node.target.id)
    return top, members


def test_stub_names_what_the_module_has():
    top, members = stub_names()
    public = {name for name in dir(_native) if not name.startswith("_")}
    assert top == public
    for name, names in members.items():
        cls = getattr(_native, name)
        have = {n for n in vars(cls) if not n.startswith("_")}
        if name in ("StreamError", "StreamTimeout"):
            have = set()
        assert names == have, (name, sorted(names ^ have))
