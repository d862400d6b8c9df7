"""research/make-blender-testset: the labels of a tiny scene of the independent set, checked against
geometry it does not use. Every part's full mask is the silhouette of the mesh posed where the
set says it lies, projected through the camera the set records (pixel centres, OpenCV's frame);
the visible mask lies inside it; area, box, visible fraction and ignore flag agree with the
masks; and where no part is seen, the region map is the drawn bin's box seen through each pixel
(research/quick_segmenter.py's ray cast). About 30 s; needs Debian's blender and blender-data
(tools/install-deps --blender, which tools/test runs)."""

import json
import os
import shutil
import subprocess
import sys

import cv2
import numpy as np
import pytest

from conftest import SOURCE

sys.path.insert(0, os.path.join(SOURCE, "research"))
import quick_segmenter  # noqa: E402
from stackgen.coco import decode_segmentation  # noqa: E402

HAS_BLENDER = shutil.which("blender") is not None and os.path.isdir(
    "/usr/share/blender/datafiles/studiolights/world")


def mesh(path):
    """The vertices (mm) and triangles of an OBJ file (polygons fanned)."""
    vertices, triangles = [], []
    with open(path) as file:
        for line in file:
            fields = line.split()
            if fields and fields[0] == "v":
                vertices.append([float(x) for x in fields[1:4]])
            elif fields and fields[0] == "f":
                corners = [int(f.split("/")[0]) - 1 for f in fields[1:]]
                triangles += [[corners[0], corners[k], corners[k + 1]]
                              for k in range(1, len(corners) - 1)]
    return np.array(vertices), np.array(triangles)


def silhouette(vertices, triangles, pose, camera, height, width):
    """The pixels whose centres the posed mesh covers."""
    rotation = np.array(pose["rotation"]).reshape(3, 3)
    world = vertices @ rotation.T + np.array(pose["translation_mm"])
    camera_rotation = np.array(camera["world_from_camera"]["rotation"]).reshape(3, 3)
    seen = (world - np.array(camera["world_from_camera"]["translation_mm"])) @ camera_rotation
    uv = np.stack([camera["fx"] * seen[:, 0] / seen[:, 2] + camera["cx"],
                   camera["fy"] * seen[:, 1] / seen[:, 2] + camera["cy"]], axis=1)
    mask = np.zeros((height, width), np.uint8)
    for triangle in triangles:
        cv2.fillPoly(mask, [np.round(uv[triangle] * 256).astype(np.int32)], 1, shift=8)
    return mask.astype(bool)


@pytest.mark.skipif(not HAS_BLENDER, reason="needs Debian's blender and blender-data "
                                            "(tools/install-deps --blender; tools/test runs it)")
def test_tiny_scene_labels_match_the_geometry(tmp_path):
    out = str(tmp_path / "set")
    # a scene of a wide recipe: a tote of a drawn size, the camera turned any way
    result = subprocess.run(
        [os.path.join(SOURCE, "research", "make-blender-testset"), "--out", out, "--recipe", "shop",
         "--count", "1", "--parts", "3", "--samples", "1", "--width", "320", "--height", "240",
         "--seed", "3"], capture_output=True, text=True, timeout=600,
        env=dict(os.environ, BLENDER_THREADS="2"))
    assert result.returncode == 0, result.stderr[-2000:]
    assert not os.path.exists(out + ".tmp")
    with open(os.path.join(out, "annotations.json")) as file:
        coco = json.load(file)
    (image,) = coco["images"]
    height, width = image["height"], image["width"]
    camera = image["stackgen"]["camera"]
    vertices, triangles = mesh(os.path.join(SOURCE, "config", "models", "corner_connector.obj"))
    assert len(coco["annotations"]) >= 2
    seen = np.zeros((height, width), bool)
    for annotation in coco["annotations"]:
        visible = decode_segmentation(annotation["segmentation"], height, width).astype(bool)
        full = decode_segmentation(annotation["amodal_segmentation"], height, width).astype(bool)
        drawn = silhouette(vertices, triangles, annotation["world_from_object"], camera, height,
                           width)
        # the full mask is the posed mesh's silhouette (a pixel's worth of edge apart)
        assert (drawn & full).sum() / (drawn | full).sum() > 0.93, annotation["id"]
        assert not (visible & ~full).any() and not (visible & seen).any()
        seen |= visible
        ys, xs = np.nonzero(visible)
        assert annotation["area"] == visible.sum()
        assert annotation["bbox"] == [xs.min(), ys.min(), xs.max() - xs.min() + 1,
                                      ys.max() - ys.min() + 1]
        fraction = visible.sum() / full.sum()
        assert annotation["visib_fract"] == pytest.approx(fraction, abs=1e-4)
        assert annotation["iscrowd"] == (0 if fraction >= 0.3 else 1)
    # where no part is seen: floor, walls and rim, or the table, as the drawn box bin is seen
    regions = cv2.imread(os.path.join(out, "regions", "000000.png"), cv2.IMREAD_GRAYSCALE)
    expected = quick_segmenter.box_bin_regions(camera, image["stackgen"]["bin_size_mm"], height,
                                               width)
    free = ~seen
    assert (regions[free] == expected[free]).mean() > 0.995
    assert set(np.unique(regions[free])) == {0, 1, 2}
