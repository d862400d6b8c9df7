"""research/image_stats.py: the figures of two tiny COCO sets of known pixels, ignore regions left
out of the part figures, and bad command lines refused in one line before anything is written."""

import json
import os
import subprocess
import sys

import cv2
import numpy as np
import pytest

from conftest import SOURCE

PROGRAM = os.path.join(SOURCE, "research", "image_stats.py")


def run(*args):
    return subprocess.run([sys.executable, PROGRAM, *args], capture_output=True, text=True,
                          timeout=120)


def rle(mask):
    flat = mask.flatten(order="F")
    edges = np.concatenate(([0], np.flatnonzero(np.diff(flat)) + 1, [flat.size]))
    counts = np.diff(edges).tolist()
    if flat[0]:
        counts = [0] + counts
    return {"counts": counts, "size": list(mask.shape)}


def make_coco(folder, parts):
    """One 40 x 60 image per entry of `parts` (RGB of a 20 x 20 part on a grey-100 floor), plus an
    ignore region of pure blue in the corner of each, which must count in no part figure."""
    os.makedirs(os.path.join(folder, "images"))
    images, annotations = [], []
    for i, rgb in enumerate(parts):
        image = np.full((40, 60, 3), 100, np.uint8)
        image[10:30, 10:30] = rgb
        image[0:5, 50:60] = (0, 0, 255)
        for k, (y0, y1, x0, x1) in enumerate([(10, 30, 10, 30), (0, 5, 50, 60)]):
            mask = np.zeros((40, 60), np.uint8)
            mask[y0:y1, x0:x1] = 1
            annotations.append({"id": 10 * i + k + 1, "image_id": i + 1, "category_id": 1,
                                "iscrowd": k, "segmentation": rle(mask)})
        cv2.imwrite(os.path.join(folder, "images", "%d.png" % i), image[..., ::-1].copy())
        images.append({"id": i + 1, "file_name": "%d.png" % i, "width": 60, "height": 40})
    with open(os.path.join(folder, "annotations.json"), "w") as file:
        json.dump({"images": images, "annotations": annotations,
                   "categories": [{"id": 1, "name": "part"}]}, file)


# a white part is clipped and grey; a red one saturated (255) at OpenCV's grey 76; the medians of
# three images and the blue ignore region nowhere in the part figures
def test_known_pixels_give_known_figures(tmp_path):
    make_coco(str(tmp_path / "a"), [(255, 255, 255), (255, 0, 0), (255, 255, 255)])
    make_coco(str(tmp_path / "b"), [(200, 200, 200)])
    out = tmp_path / "figures.json"
    result = run(str(tmp_path / "a"), str(tmp_path / "b"), "--json", str(out))
    assert result.returncode == 0, result.stderr
    figures = json.loads(out.read_text())
    a, b = figures[str(tmp_path / "a")], figures[str(tmp_path / "b")]
    assert a["images"] == 3 and b["images"] == 1
    assert a["part_grey"]["median"] == pytest.approx(255)
    assert a["part_grey"]["p10"] == pytest.approx(76 + 0.2 * (255 - 76))
    assert a["part_saturation"]["median"] == 0 and a["part_saturation"]["p90"] > 200
    assert a["part_clipped"]["median"] == 1 and a["part_clipped"]["p10"] == pytest.approx(0.2)
    assert b["part_grey"]["median"] == pytest.approx(200) and b["part_clipped"]["median"] == 0
    assert b["part_saturation"]["median"] == 0
    # the whole image: 400 part pixels of 200, 50 blue (grey 29) and 1,950 of 100
    grey = (400 * 200 + 50 * 29 + 1950 * 100) / 2400
    assert b["grey"]["median"] == pytest.approx(grey, abs=0.01)
    assert b["saturation"]["median"] == pytest.approx(50 * 255 / 2400, abs=0.01)
    assert b["grey_sd"]["median"] > 0
    assert "part saturation" in result.stdout and str(tmp_path / "b") in result.stdout
    # --limit reads the first images only
    first = run(str(tmp_path / "a"), "--limit", "1", "--json", str(out))
    assert first.returncode == 0 and json.loads(out.read_text())[str(tmp_path / "a")]["images"] == 1


# a folder without annotations.json, --limit 0 or a --json in a missing folder: one line naming
# it, exit 2, no file written
def test_bad_command_lines_say_what_and_exit_2(tmp_path):
    make_coco(str(tmp_path / "a"), [(255, 255, 255)])
    missing = run(str(tmp_path / "a"), str(tmp_path / "nothing"))
    assert missing.returncode == 2 and "nothing: no annotations.json" in missing.stderr
    assert missing.stdout == ""
    limit = run(str(tmp_path / "a"), "--limit", "0")
    assert limit.returncode == 2 and "--limit 0" in limit.stderr
    nowhere = run(str(tmp_path / "a"), "--json", str(tmp_path / "no" / "f.json"))
    assert nowhere.returncode == 2 and "--json" in nowhere.stderr
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "annotations.json").write_text("{")
    bad = run(str(tmp_path / "bad"))
    assert bad.returncode == 2 and "annotations.json" in bad.stderr
    for result in (missing, limit, nowhere, bad):
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("research/image-stats: error:"), lines
    assert not (tmp_path / "no").exists()
