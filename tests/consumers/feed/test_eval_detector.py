"""tools/eval_detector.py: bad command lines are refused in one line, and a tiny run (two steps on
a two-image COCO folder) trains, scores and writes its JSON."""

import json
import os
import subprocess
import sys

import cv2
import numpy as np

ROOT = os.environ.get("STACKGEN_SOURCE_DIR",
                      os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(
                          os.path.abspath(__file__))))))
PROGRAM = os.path.join(ROOT, "tools", "eval_detector.py")


def run(*args):
    return subprocess.run([sys.executable, PROGRAM, *args], capture_output=True, text=True,
                          timeout=600)


def make_coco(folder):
    """Two 480 x 640 images, each with two bright squares on grey, one of them an ignore region."""
    os.makedirs(os.path.join(folder, "images"))
    images, annotations = [], []
    for i in range(2):
        image = np.full((480, 640, 3), 90, np.uint8)
        for k, (x, y) in enumerate([(100 + 40 * i, 120), (380, 260 - 30 * i)]):
            image[y:y + 90, x:x + 90] = 220
            mask = np.zeros((480, 640), np.uint8)
            mask[y:y + 90, x:x + 90] = 1
            flat = mask.flatten(order="F")
            edges = np.concatenate(([0], np.flatnonzero(np.diff(flat)) + 1, [flat.size]))
            annotations.append({"id": 10 * i + k + 1, "image_id": i + 1, "category_id": 1,
                                "iscrowd": k, "bbox": [x, y, 90, 90], "area": 8100,
                                "segmentation": {"counts": np.diff(edges).tolist(),
                                                 "size": [480, 640]}})
        cv2.imwrite(os.path.join(folder, "images", "%d.png" % i), image)
        images.append({"id": i + 1, "file_name": "%d.png" % i, "width": 640, "height": 480})
    with open(os.path.join(folder, "annotations.json"), "w") as file:
        json.dump({"images": images, "annotations": annotations,
                   "categories": [{"id": 1, "name": "square"}]}, file)


def test_bad_command_lines_say_what_and_exit_2(tmp_path):
    missing = run("--config", str(tmp_path / "missing.pbtxt"))
    assert missing.returncode == 2
    assert "missing.pbtxt" in missing.stderr and len(missing.stderr.strip().splitlines()) == 1
    config = os.path.join(ROOT, "config", "default.pbtxt")
    not_coco = run("--config", config, "--test", str(tmp_path))
    assert not_coco.returncode == 2 and "annotations.json" in not_coco.stderr
    alone = run("--config", config, "--no-held-out")
    assert alone.returncode == 2 and "--no-held-out" in alone.stderr


def test_a_tiny_run_trains_scores_and_writes_json(tmp_path):
    folder = str(tmp_path / "squares")
    make_coco(folder)
    out = str(tmp_path / "results.json")
    result = run("--config", os.path.join(ROOT, "config", "default.pbtxt"), "--train-dir", folder,
                 "--test", folder, "--no-held-out", "--steps", "2", "--scale", "0.25",
                 "--threads", "2", "--out", out)
    assert result.returncode == 0, result.stderr
    assert "MIoU" in result.stdout
    with open(out) as file:
        written = json.load(file)
    (scores,) = written["results"]
    assert scores["images"] == 2
    # one real square per image: found or missed, the ignore regions never count
    assert scores["tp"] + scores["fn"] == 2
    assert written["steps"] == 2 and written["mode"] == "cpu"
