"""Labelled image folders on disk (stackgen.coco), read as images and masks for training and
evaluation: COCO instance segmentation (what stackgen-coco writes, or any folder with an
annotations.json: masks as compressed RLE strings, cocoapi's form, uncompressed RLE count lists,
or polygons) and labelme (one X.json per image: polygons and rectangles), the usual output of
labelling a few photos by hand. open_labelled_folder picks the reader.
"""

import glob
import json
import os
from typing import Dict, Optional, Tuple, Union

import cv2
import numpy as np

from ._native import decode_rle

__all__ = ["CocoDataset", "LabelmeDataset", "open_labelled_folder", "decode_segmentation"]


def decode_segmentation(segmentation: Union[dict, list], height: int,
                        width: int) -> np.ndarray:
    """The mask of one COCO segmentation.

    Args:
        segmentation: an RLE dict (counts a compressed string or a list of run lengths,
            column-major, zeros first) or a list of polygons.
        height: the image's height in pixels.
        width: the image's width in pixels.

    Returns:
        (height, width) uint8 0/1 mask.

    Raises:
        ValueError: an RLE whose size is not the image's, or whose counts do not cover the
            image.
    """
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

    Args:
        folder: holds annotations.json; image files are looked up in folder/images, then
            folder.

    Raises:
        ValueError: annotations.json is missing or not COCO (the message names the file).
    """

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
        """The path of an image file.

        stackgen-coco's file names are relative to folder/images, other tools' to folder.

        Args:
            index: the image's index.

        Returns:
            The path of the image file.
        """
        name = self.images[index]["file_name"]
        path = os.path.join(self._base, name)
        return path if os.path.exists(path) else os.path.join(self.folder, name)

    def image(self, index: int) -> np.ndarray:
        """Reads an image.

        Args:
            index: the image's index.

        Returns:
            (H, W, 3) uint8 RGB (a gray image repeated in three channels).

        Raises:
            ValueError: the image cannot be read (the message names the file).
        """
        path = self.image_path(index)
        bgr = cv2.imread(path, cv2.IMREAD_COLOR)
        if bgr is None:
            raise ValueError("%s: cannot read the image" % path)
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)

    def target(self, index: int) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The instances of an image.

        Args:
            index: the image's index.

        Returns:
            (masks, labels, iscrowd): masks (K, H, W) uint8 0/1, labels (K) category ids,
            iscrowd (K) bool.

        Raises:
            ValueError: an annotation's segmentation is missing or cannot be decoded (the
                message names the file and the annotation).
        """
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


class LabelmeDataset:
    """The images of a folder of labelme files, in file-name order, with their instance masks.

    Each file, X.json, names its image in imagePath, a path relative to the file. The dataset
    has the same methods as CocoDataset. Shapes of type polygon and rectangle become masks;
    shapes with the same label and a group_id are one instance (labelme's convention), every
    other shape an instance of its own.

    Args:
        folder: holds the labelme files.
        class_ids: turns labels into class ids ({label: id}); without it the folder must use
            one label, which becomes class 1 (one part, as stackgen's default config).

    Raises:
        ValueError: for anything else: a shape of another type, a file that is not labelme's,
            no .json file, more than one label without class_ids, a label without a class id
            (the message names the file and shape, or the folder).
    """

    def __init__(self, folder: str, class_ids: Optional[Dict[str, int]] = None) -> None:
        self.folder = folder
        paths = sorted(glob.glob(os.path.join(folder, "*.json")))
        if not paths:
            raise ValueError("%s: no labelme .json files" % folder)
        self._records = []
        labels = set()
        for path in paths:
            try:
                with open(path) as file:
                    record = json.load(file)
                shapes = record["shapes"]
                image_path = record["imagePath"]
                height, width = int(record["imageHeight"]), int(record["imageWidth"])
            except (OSError, ValueError, KeyError, TypeError) as error:
                raise ValueError("%s: not a labelme file: %s" % (path, error)) from None
            for index, shape in enumerate(shapes):
                if not isinstance(shape, dict) or not isinstance(shape.get("label"), str):
                    raise ValueError("%s: shape %d has no label" % (path, index))
                kind = shape.get("shape_type") or "polygon"
                if kind not in ("polygon", "rectangle"):
                    raise ValueError("%s: shape %d (%s): a %s, not a polygon or rectangle" %
                                     (path, index, shape.get("label"), kind))
                labels.add(shape.get("label"))
            # labelme on Windows writes imagePath with backslashes
            image_path = str(image_path).replace("\\", "/")
            self._records.append((path, os.path.join(os.path.dirname(path), image_path),
                                  height, width, shapes))
        if class_ids is None:
            if len(labels) > 1:
                raise ValueError("%s: labels %s: give class_ids={label: id} for more than one" %
                                 (folder, sorted(labels)))
            class_ids = {label: 1 for label in labels}
        unknown = sorted(labels - set(class_ids))
        if unknown:
            raise ValueError("%s: labels %s have no class id in class_ids" % (folder, unknown))
        self.class_ids = dict(class_ids)
        self.categories = {v: k for k, v in self.class_ids.items()}

    def __len__(self):
        return len(self._records)

    def image_path(self, index: int) -> str:
        """The path of an image file.

        Args:
            index: the image's index.

        Returns:
            The path of the image file (imagePath, relative to the labelme file's folder).
        """
        return self._records[index][1]

    def image(self, index: int) -> np.ndarray:
        """Reads an image.

        Args:
            index: the image's index.

        Returns:
            (H, W, 3) uint8 RGB (a gray image repeated in three channels).

        Raises:
            ValueError: the image cannot be read or its size is not the one the labelme file
                gives (the message names both files).
        """
        path, image_path, height, width, _ = self._records[index]
        bgr = cv2.imread(image_path, cv2.IMREAD_COLOR)
        if bgr is None:
            raise ValueError("%s: cannot read the image %s" % (path, image_path))
        if bgr.shape[:2] != (height, width):
            raise ValueError("%s: the image %s is %dx%d, the file says %dx%d" % (
                path, image_path, bgr.shape[1], bgr.shape[0], width, height))
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)

    def target(self, index: int) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The instances of an image.

        Args:
            index: the image's index.

        Returns:
            (masks, labels, iscrowd): masks (K, H, W) uint8 0/1, labels (K) class ids, iscrowd
            (K) bool (all False).

        Raises:
            ValueError: a shape's points are missing, malformed or too few (the message names
                the file and shape).
        """
        path, _, height, width, shapes = self._records[index]
        instances = {}  # key -> (label, [shapes])
        for number, shape in enumerate(shapes):
            group = shape.get("group_id")
            key = ("group", shape["label"], group) if group is not None else ("shape", number)
            instances.setdefault(key, (shape["label"], []))[1].append((number, shape))
        masks = np.zeros((len(instances), height, width), dtype=np.uint8)
        labels = np.zeros(len(instances), dtype=np.int64)
        for k, (label, members) in enumerate(instances.values()):
            labels[k] = self.class_ids[label]
            for number, shape in members:
                try:
                    points = np.asarray(shape["points"], dtype=np.float64).reshape(-1, 2)
                except (KeyError, ValueError, TypeError) as error:
                    raise ValueError("%s: shape %d: points: %s" % (path, number, error)) from None
                if shape.get("shape_type") == "rectangle":
                    if len(points) != 2:
                        raise ValueError("%s: shape %d: a rectangle needs 2 points, not %d" %
                                         (path, number, len(points)))
                    (x0, y0), (x1, y1) = points.min(axis=0), points.max(axis=0)
                    points = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
                elif len(points) < 3:
                    raise ValueError("%s: shape %d: a polygon needs 3 points or more, not %d" %
                                     (path, number, len(points)))
                cv2.fillPoly(masks[k], [np.round(points).astype(np.int32)], 1)
        return masks, labels, np.zeros(len(instances), dtype=bool)


def open_labelled_folder(folder: str, class_ids: Optional[Dict[str, int]] = None
                         ) -> Union[CocoDataset, LabelmeDataset]:
    """The reader for a labelled folder.

    Args:
        folder: a COCO folder (with annotations.json) or a folder of labelme files.
        class_ids: as for LabelmeDataset.

    Returns:
        CocoDataset when the folder holds annotations.json, else LabelmeDataset.

    Raises:
        ValueError: the folder does not exist or is neither (the message names the folder);
            or as the readers raise it.
    """
    if not os.path.isdir(folder):
        raise ValueError("%s: no such folder" % folder)
    if os.path.exists(os.path.join(folder, "annotations.json")):
        return CocoDataset(folder)
    if glob.glob(os.path.join(folder, "*.json")):
        return LabelmeDataset(folder, class_ids)
    raise ValueError("%s: neither a COCO folder (annotations.json) nor labelme files (*.json)" %
                     folder)
