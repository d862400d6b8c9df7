"""Config files for the Python tests, shared by the tests' conftest.py files."""

import os
import re


def quick_config(folder, source, halls=1):
    """The config `source` written into `folder` as quick.pbtxt, with `halls` procedural
    environments instead of its 8: a generator, and `stackgen --check`, prepares every
    environment when it starts, most of a short run's time (docs/results.md, "Tests"). The piles are the config's (same parts, camera, physics); the images
    are lit by fewer environments. Relative mesh paths are made absolute, as the copy is read
    from another folder. Returns its path."""
    with open(source) as file:
        text = file.read()
    base = os.path.dirname(os.path.abspath(source))

    def absolute(match):
        return '%s%s"' % (match.group(1), os.path.normpath(os.path.join(base, match.group(2))))

    text = re.sub(r'(\b(?:mesh|collision_mesh):\s*")([^"/][^"]*)"', absolute, text)
    assert "rendering {" not in text and "procedural_halls" not in text, source
    text += "\nrendering {\n  procedural_halls: %d\n}\n" % halls
    path = os.path.join(str(folder), "quick.pbtxt")
    with open(path, "w") as file:
        file.write(text)
    return path
