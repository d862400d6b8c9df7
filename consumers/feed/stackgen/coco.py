"""COCO instance-segmentation datasets on disk (stackgen.coco): what stackgen-coco writes, or any
COCO folder with an annotations.json, read as images and masks for training and evaluation.

Masks may be compressed RLE strings (cocoapi's form, which stackgen-coco writes), uncompressed
RLE count lists, or polygons.
"""

import json
import os
from typing import Tuple, Union

import cv2
import numpy as np

from ._native import decode_rle

__all__ = ["CocoDataset", "decode_segmentation"]


def decode_segmentation(segmentation: Union[dict, list], height: int,
                        width: int) -> np.ndarray:
    """(height, width) uint8 0/1 mask of one COCO segmentation: an RLE dict (counts a compressed
    string or a list of run lengths, column-major, zeros first) or a list of polygons."""
    if isinstance(segmentation, dict):
        counts = segmentation.get("counts")
        size = segmentation.get("size", [height, width])
        if list(size) != [height, width]:
            raise ValueError("an RLE of size %s in an image of %dx%d" % (size, height, width))
        if isinstance(counts, str):
            return decode_rle(counts, height, width)
        runs = np.asarray(counts, dtype=np.int64)
        if runs.sum() != height * width or (runs < 0).any():
            raise ValueError("RLE counts cover %d pixels, not %d" % (runs.sum(), height * width))
        values = np.zeros(len(runs), dtype=np.uint8)
        values[1::2] = 1
        flat = np.repeat(values, runs)
        return np.ascontiguousarray(flat.reshape(width, height).T)
    mask = np.zeros((height, width), dtype=np.uint8)
    for polygon in segmentation:
        points = np.asarray(polygon, dtype=np.float64).reshape(-1, 2)
        cv2.fillPoly(mask, [np.round(points).astype(np.int32)], 1)
    return mask


class CocoDataset:
    """The images of a COCO folder in file-name order, with their instance masks.

    folder: holds annotations.json; image files are looked up in folder/images, then folder.
    Raises ValueError naming the file when annotations.json is missing or not COCO."""

    def __init__(self, folder: str) -> None:
        self.folder = folder
        path = os.path.join(folder, "annotations.json")
        try:
            with open(path) as file:
                coco = json.load(file)
            images = sorted(coco["images"], key=lambda image: image["file_name"])
            annotations = coco["annotations"]
        except (OSError, ValueError, KeyError, TypeError) as error:
            raise ValueError("%s: not a COCO annotations file: %s" % (path, error)) from None
        self.images = images
        self.categories = {c["id"]: c["name"] for c in coco.get("categories", [])}
        self._annotations = {image["id"]: [] for image in images}
        for annotation in annotations:
            if annotation.get("image_id") in self._annotations:
                self._annotations[annotation["image_id"]].append(annotation)
        base = os.path.join(folder, "images")
        self._base = base if os.path.isdir(base) else folder

    def __len__(self):
        return len(self.images)

    def image_path(self, index: int) -> str:
        """stackgen-coco's file names are relative to folder/images, other tools' to folder."""
        name = self.images[index]["file_name"]
        path = os.path.join(self._base, name)
        return path if os.path.exists(path) else os.path.join(self.folder, name)

    def image(self, index: int) -> np.ndarray:
        """(H, W, 3) uint8 RGB (a gray image repeated in three channels)."""
        path = self.image_path(index)
        bgr = cv2.imread(path, cv2.IMREAD_COLOR)
        if bgr is None:
            raise ValueError("%s: cannot read the image" % path)
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)

    def target(self, index: int) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
        """masks (K, H, W) uint8 0/1, labels (K) category ids, iscrowd (K) bool."""
        image = self.images[index]
        height, width = image["height"], image["width"]
        annotations = self._annotations[image["id"]]
        masks = np.zeros((len(annotations), height, width), dtype=np.uint8)
        for k, annotation in enumerate(annotations):
            try:
                masks[k] = decode_segmentation(annotation["segmentation"], height, width)
            except (KeyError, ValueError) as error:
                raise ValueError("%s: annotation %s: %s" % (
                    os.path.join(self.folder, "annotations.json"), annotation.get("id"),
                    error)) from None
        labels = np.array([a.get("category_id", 1) for a in annotations], dtype=np.int64)
        iscrowd = np.array([bool(a.get("iscrowd", 0)) for a in annotations], dtype=bool)
        return masks, labels, iscrowd
