"""tools/coco-to-yolo on a real COCO dataset (stackgen-coco reading the fixture log): the labels
read back as Ultralytics reads them, each outline rasterised at the image's size, cover the COCO
mask of the same object; ignore regions are left out; data.yaml names the splits and classes; a
bad input writes nothing.

CTest runs this file with Debian's /usr/bin/python3 -m pytest; PYTHONPATH is the build's
python/ folder."""

import json
import os
import subprocess
import sys

import cv2
import numpy as np

from conftest import BIN, SOURCE, TINY_LOG
from stackgen.coco import CocoDataset

CONVERT = os.path.join(SOURCE, "tools", "coco_to_yolo.py")


def convert(*args):
    return subprocess.run([sys.executable, CONVERT, *map(str, args)], capture_output=True,
                          text=True, timeout=120)


def test_outlines_cover_the_masks(tmp_path):
    coco = tmp_path / "coco"
    made = subprocess.run([os.path.join(BIN, "stackgen-coco"), "--lcm-url",
                           "file://%s?speed=0" % TINY_LOG, "--open-bus", "--out", str(coco)],
                          capture_output=True, text=True, timeout=120)
    assert made.returncode == 0, made.stderr
    yolo = tmp_path / "yolo"
    result = convert("train=%s" % coco, "val=%s" % coco, "--out", yolo)
    assert result.returncode == 0, result.stderr
    data = (yolo / "data.yaml").read_text()
    assert "train: images/train\nval: images/val\nnames:\n  0: \"corner_connector\"\n" in data
    assert "warning" not in result.stderr
    # one folder alone: data.yaml's val is the training set, and the converter says so
    alone = convert(coco, "--out", tmp_path / "alone")
    assert alone.returncode == 0, alone.stderr
    assert "val: images/train\n" in (tmp_path / "alone" / "data.yaml").read_text()
    assert "warning: one split only" in alone.stderr, alone.stderr

    dataset = CocoDataset(str(coco))
    ious, ignored = [], 0
    for index in range(len(dataset)):
        image = dataset.images[index]
        width, height = image["width"], image["height"]
        masks, labels, iscrowd = dataset.target(index)
        ignored += int(iscrowd.sum())
        stem = os.path.splitext(os.path.basename(image["file_name"]))[0]
        assert (yolo / "images" / "train" / os.path.basename(image["file_name"])).is_file()
        lines = (yolo / "labels" / "train" / (stem + ".txt")).read_text().splitlines()
        kept = [mask for mask, crowd in zip(masks, iscrowd) if not crowd and mask.any()]
        assert len(lines) == len(kept)
        for line, mask in zip(lines, kept):
            fields = line.split()
            assert fields[0] == "0" and len(fields) % 2 == 1 and len(fields) >= 7
            points = np.array(fields[1:], dtype=np.float64).reshape(-1, 2)
            assert (points >= 0).all() and (points <= 1).all()
            pixels = np.round(points * [width, height]).astype(np.int32)
            drawn = np.zeros((height, width), np.uint8)
            cv2.fillPoly(drawn, [pixels], 1)
            ious.append((drawn & mask).sum() / (drawn | mask).sum())
    assert ignored > 0  # the fixture holds ignore regions: they are left out above
    # pieces joined by cuts gain the cut's pixels (one small part in three pieces: 0.84)
    assert min(ious) > 0.8 and np.mean(ious) > 0.98, sorted(ious)[:5]
    assert sorted(ious)[1] > 0.95, sorted(ious)[:5]


def test_bad_input_writes_nothing(tmp_path):
    out = tmp_path / "yolo"
    result = convert(tmp_path / "nowhere", "--out", out)
    assert result.returncode == 2 and "no annotations.json" in result.stderr
    assert result.stderr.count("\n") == 1
    folder = tmp_path / "broken"
    folder.mkdir()
    (folder / "annotations.json").write_text(json.dumps({"images": [], "annotations": []}))
    result = convert(folder, "--out", out)
    assert result.returncode == 1 and "no categories" in result.stderr
    assert not out.exists() and not [p for p in os.listdir(tmp_path) if ".tmp-" in p]
