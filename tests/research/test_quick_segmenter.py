"""research/quick_segmenter.py (eval-detector's quick mode): the targets it learns, the instances it
reads back from a prediction, the score of a perfect and an empty one, and the region a box bin
shows through each pixel."""

import os
import sys

import numpy as np
import pytest

from conftest import SOURCE

sys.path.insert(0, os.path.join(SOURCE, "research"))
import quick_segmenter as qs  # noqa: E402
from stackgen.metrics import (REGION_BACKGROUND, REGION_FLOOR, REGION_WALLS,  # noqa: E402
                              DetectionScores, ForegroundScores)


def two_touching_parts(height=48, width=64):
    """Two rectangles side by side (touching), one ignore region apart, as COCO masks."""
    masks = np.zeros((3, height, width), np.uint8)
    masks[0, 10:30, 10:30] = 1
    masks[1, 10:30, 30:50] = 1
    masks[2, 36:44, 4:12] = 1
    return masks, np.array([False, False, True])


# the outline is each instance's pixels next to another instance or the background, the image
# border makes none, and an ignore region is neither part nor background
def test_targets_mark_outlines_between_touching_parts():
    masks, crowd = two_touching_parts()
    ids, ignore = qs.label_map(masks, crowd)
    target = qs.class_targets(ids, ignore, 48, 64)
    assert target[20, 29] == qs.OUTLINE and target[20, 30] == qs.OUTLINE  # where they touch
    assert target[10, 15] == qs.OUTLINE and target[20, 20] == qs.INTERIOR
    assert target[40, 8] == qs.IGNORE and target[0, 0] == qs.BACKGROUND
    # a part cut by the image's edge has no outline there
    edge = np.zeros((1, 48, 64), np.uint8)
    edge[0, 0:10, 0:10] = 1
    at_border = qs.class_targets(*qs.label_map(edge, np.array([False])), 48, 64)
    assert at_border[0, 5] == qs.INTERIOR and at_border[9, 5] == qs.OUTLINE
    # at half size the ids are read at the centres of 2 x 2 blocks
    half = qs.class_targets(ids, ignore, 24, 32)
    assert half[10, 10] == qs.INTERIOR and half[10, 14] == qs.OUTLINE


# a prediction that matches the truth gives back both touching parts, each at IoU > 0.6 (the
# outlines grown back), and foreground IoU 1; an empty one scores 0 on both
def test_perfect_and_empty_predictions_score_one_and_zero():
    masks, crowd = two_touching_parts()
    ids, ignore = qs.label_map(masks, crowd)
    target = qs.class_targets(ids, ignore, 48, 64)
    probabilities = np.zeros((3, 48, 64), np.float32)
    for k in (qs.BACKGROUND, qs.INTERIOR, qs.OUTLINE):
        probabilities[k][target == k] = 0.9
    probabilities[qs.BACKGROUND][target == qs.IGNORE] = 0.9
    found, scores, foreground = qs.instances(probabilities, min_px=4)
    assert len(found) == 2 and np.all(scores > 0.5)
    detections = DetectionScores()
    detections.update(scores, found, masks.astype(bool), crowd)
    assert detections.result()["miou"] == pytest.approx(1.0)
    pixels = ForegroundScores()
    pixels.update(foreground, ids > 0, ignore)
    assert pixels.result()["iou"] == pytest.approx(1.0)

    none, none_scores, nothing = qs.instances(np.stack([np.ones((48, 64), np.float32),
                                                        np.zeros((48, 64), np.float32),
                                                        np.zeros((48, 64), np.float32)]))
    assert len(none) == 0
    empty = DetectionScores()
    empty.update(none_scores, none, masks.astype(bool), crowd)
    assert empty.result()["miou"] == 0.0 and empty.result()["fn"] == 2
    zero = ForegroundScores()
    zero.update(nothing, ids > 0, ignore)
    assert zero.result()["iou"] == 0.0


# looking straight down from 450 mm at the default bin (200 x 150 x 100 mm inside, 8 mm walls):
# the image centre is floor, the inner wall and the rim are walls, beyond the rim the table
def test_box_bin_regions_straight_down():
    camera = {"fx": 800.0, "fy": 800.0, "cx": 319.5, "cy": 239.5,
              "world_from_camera": {"translation_mm": [0, 0, 450],
                                    "rotation": [1, 0, 0, 0, -1, 0, 0, 0, -1]}}
    regions = qs.box_bin_regions(camera, (200, 150, 100, 8), 480, 640)
    row = 240
    # the inner wall at x = 100 mm spans 800 * 100 / 450 = 178 to 800 * 100 / 350 = 229 px from
    # the centre; the rim (x up to 108 mm at 100 mm high) reaches 247 px
    assert regions[row, 320] == REGION_FLOOR
    assert regions[row, 320 + 170] == REGION_FLOOR
    assert regions[row, 320 + 200] == REGION_WALLS
    assert regions[row, 320 + 240] == REGION_WALLS
    assert regions[row, 320 + 260] == REGION_BACKGROUND
    assert regions[row, 320 - 200] == REGION_WALLS
    # along y the inner wall at 75 mm: 133 to 171 px from the centre
    assert regions[240 + 120, 320] == REGION_FLOOR
    assert regions[240 + 150, 320] == REGION_WALLS
    assert regions[0, 0] == REGION_BACKGROUND


# --unet-levels: each level doubles what the network sees around a pixel; predict pads any image
# size to the deepest level's multiple and returns probabilities at the image's own size
@pytest.mark.parametrize("levels, weights, seen_px", [(4, 122483, 101), (5, 491891, 205)])
def test_levels_set_the_weights_and_what_a_pixel_sees(levels, weights, seen_px):
    import torch
    model = qs.build_model(0, levels).eval()
    assert sum(p.numel() for p in model.parameters()) == weights
    assert model.multiple == 2 ** (levels - 1)
    x = torch.zeros(1, 3, 320, 320, requires_grad=True)
    model(x)[0, 1, 160, 160].backward()
    rows = (x.grad.abs().sum(dim=(0, 1)) > 0).any(dim=1).nonzero()
    assert int(rows.max() - rows.min() + 1) == seen_px
    image = np.full((50, 70, 3), 128, np.uint8)  # 25 x 35 at half size: padded to the multiple
    probabilities = qs.predict(model, image, 0.5)
    assert probabilities.shape == (3, 50, 70)
    assert np.allclose(probabilities.sum(axis=0), 1, atol=1e-5)


# --tta: the prediction averaged over the eight quarter turns and mirror images, each turned back,
# is the same whichever way the image lies; one view alone (an untrained network) is not
def test_tta_is_the_same_under_every_turn_and_mirror():
    import torch
    model = qs.build_model(0).eval()
    with torch.no_grad():  # an untrained network's classes barely differ: made to differ
        model.head.weight.mul_(100)
    # 48 x 32 at half size: no padding, which would differ between a view and its turn
    image = np.random.default_rng(0).integers(0, 256, (64, 96, 3), np.uint8)
    averaged = qs.predict(model, image, 0.5, tta=True)
    assert averaged.shape == (3, 64, 96)
    assert np.allclose(averaged.sum(axis=0), 1, atol=1e-5)
    for turns in range(4):
        for mirror in (False, True):
            view = np.rot90(image, turns)
            view = np.ascontiguousarray(view[:, ::-1] if mirror else view)
            expected = np.rot90(averaged, turns, (1, 2))
            expected = expected[:, :, ::-1] if mirror else expected
            assert np.allclose(qs.predict(model, view, 0.5, tta=True), expected, atol=1e-5)
    plain = qs.predict(model, np.ascontiguousarray(np.rot90(image)), 0.5)
    assert np.abs(plain - np.rot90(qs.predict(model, image, 0.5), 1, (1, 2))).max() > 0.05
