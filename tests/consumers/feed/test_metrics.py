"""stackgen.metrics: the paper's MIoU and COCO mask AP on masks whose answers are known by hand,
and stackgen.coco reading both RLE forms."""

import json
import os

import numpy as np
import pytest

from stackgen.coco import CocoDataset, decode_segmentation
from stackgen.metrics import DetectionScores, box_iou, mask_boxes, mask_iou


def square(x, y, size, height=40, width=60):
    mask = np.zeros((height, width), dtype=bool)
    mask[y:y + size, x:x + size] = True
    return mask


def test_mask_iou_and_crowd_regions():
    a = square(0, 0, 10)
    b = square(5, 0, 10)  # half of a: intersection 50, union 150
    iou = mask_iou(np.stack([a]), np.stack([a, b]))
    assert iou[0, 0] == pytest.approx(1.0)
    assert iou[0, 1] == pytest.approx(50 / 150)
    # a crowd region: the intersection over the prediction's own area
    crowd = mask_iou(np.stack([b]), np.stack([a]), crowd=[True])
    assert crowd[0, 0] == pytest.approx(0.5)


# one image: a found exactly, b found at IoU 0.5 (not above 0.6), c missed; one prediction on
# empty floor; one on an ignore region, which counts neither way
def test_paper_score_counts_matches_above_point_six():
    a, b, c = square(0, 0, 10), square(20, 0, 10), square(40, 20, 10)
    crowd_region = square(20, 25, 12)
    scores = DetectionScores()
    predicted = [a, square(25, 0, 10) | square(20, 0, 5), square(0, 25, 8), square(21, 26, 8)]
    scores.update([0.9, 0.8, 0.7, 0.95], predicted, [a, b, c, crowd_region],
                  [False, False, False, True])
    result = scores.result()
    iou_b = mask_iou(np.stack([predicted[1]]), np.stack([b]))[0, 0]
    assert iou_b <= 0.6
    assert (result["tp"], result["fp"], result["fn"]) == (1, 2, 2)
    assert result["miou"] == pytest.approx(1 / 5)
    # below the score threshold a prediction does not count for the paper's score
    low = DetectionScores(score_threshold=0.5)
    low.update([0.3], [a], [a])
    assert (low.tp, low.fp, low.fn) == (0, 0, 1)


def test_coco_ap_perfect_ranked_and_empty():
    truths = [square(0, 0, 10), square(20, 0, 10), square(40, 0, 10)]
    perfect = DetectionScores()
    perfect.update([0.9, 0.8, 0.7], truths, truths)
    result = perfect.result()
    assert result["ap"] == pytest.approx(1.0)
    assert result["miou"] == pytest.approx(1.0)
    # a false positive ranked above every true one: precision 1/2, 2/3, 3/4 at recall 1/3, 2/3, 1
    ranked = DetectionScores()
    ranked.update([0.99, 0.9, 0.8, 0.7], [square(0, 25, 10)] + truths, truths)
    expected = np.mean([0.75] * 101)  # interpolated: the best precision at or beyond each recall
    assert ranked.result()["ap50"] == pytest.approx(expected)
    # nothing predicted: AP 0, every truth missed
    empty = DetectionScores()
    empty.update(np.zeros(0), np.zeros((0, 40, 60), bool), truths)
    assert empty.result()["ap"] == 0.0
    assert empty.result()["fn"] == 3
    with pytest.raises(ValueError):
        DetectionScores().update([0.5, 0.4], [truths[0]], truths)


# box AP by hand: truths a, b, c (their masks' extents) and an ignore region; predictions, best
# first: one inside the ignore region (neither true nor false), one on empty floor, a exactly, b
# at IoU 0.84, c at IoU 1/3. At IoU 0.50-0.80: precision 0, 1/2, 2/3, 1/2 at recall 0, 1/3, 2/3,
# 2/3, made monotone 2/3 up to recall 2/3: 67 of the 101 recall points read 2/3. At 0.85-0.95 b
# is missed: 1/2 up to recall 1/3, 34 points.
def test_coco_box_ap_worked_by_hand():
    a, b, c = square(0, 0, 10), square(20, 0, 10), square(40, 0, 10)
    crowd_region = square(20, 25, 12)
    boxes = [[0, 20, 10, 30], [0, 0, 10, 10], [20, 0, 30, 8.4], [45, 0, 55, 10], [21, 26, 29, 34]]
    scores = DetectionScores()
    scores.update([0.95, 0.9, 0.8, 0.7, 0.97], [a] * 5, [a, b, c, crowd_region],
                  [False, False, False, True], boxes=boxes)
    assert box_iou([boxes[2]], mask_boxes([b]))[0, 0] == pytest.approx(0.84)
    result = scores.result()
    high, low = 67 / 101 * 2 / 3, 34 / 101 * 0.5
    assert result["box_ap50"] == pytest.approx(high)
    assert result["box_ap75"] == pytest.approx(high)
    assert result["box_ap"] == pytest.approx((7 * high + 3 * low) / 10)
    # given boxes of the ground truth are used as they are
    shifted = DetectionScores()
    shifted.update([0.9], [a], [a], boxes=[[0, 0, 10, 10]], truth_boxes=[[5, 0, 15, 10]])
    assert shifted.result()["box_ap50"] == 0.0
    # without predicted boxes there is no box AP; counts that disagree are refused
    masks_only = DetectionScores()
    masks_only.update([0.9], [a], [a])
    assert "box_ap" not in masks_only.result()
    with pytest.raises(ValueError, match="1 boxes for 2 scores"):
        DetectionScores().update([0.9, 0.8], [a, a], [a], boxes=[[0, 0, 1, 1]])


def test_coco_dataset_reads_compressed_and_plain_rle(tmp_path):
    mask = np.zeros((4, 5), dtype=np.uint8)
    mask[1:3, 2:4] = 1
    # column-major runs starting with zeros: 9 zeros, 2 ones, 2 zeros, 2 ones, 5 zeros
    counts = [9, 2, 2, 2, 5]
    assert (decode_segmentation({"counts": counts, "size": [4, 5]}, 4, 5) == mask).all()
    # cocoapi's compressed string of the same runs (each run as 5-bit groups, from the third
    # on as the difference to the run two before)
    compressed = "92203"
    assert (decode_segmentation({"counts": compressed, "size": [4, 5]}, 4, 5) == mask).all()
    with pytest.raises(ValueError):
        decode_segmentation({"counts": [9, 2], "size": [4, 5]}, 4, 5)

    os.makedirs(tmp_path / "images")
    import cv2
    cv2.imwrite(str(tmp_path / "images" / "a.png"), np.full((4, 5, 3), 128, np.uint8))
    json.dump({"images": [{"id": 7, "file_name": "a.png", "width": 5, "height": 4}],
               "annotations": [{"id": 1, "image_id": 7, "category_id": 1, "iscrowd": 1,
                                "segmentation": {"counts": counts, "size": [4, 5]}}],
               "categories": [{"id": 1, "name": "part"}]}, open(tmp_path / "annotations.json", "w"))
    dataset = CocoDataset(str(tmp_path))
    assert len(dataset) == 1
    masks, labels, iscrowd = dataset.target(0)
    assert (masks[0] == mask).all() and labels.tolist() == [1] and iscrowd.tolist() == [True]
    assert dataset.image(0).shape == (4, 5, 3)
    with pytest.raises(ValueError, match="annotations.json"):
        CocoDataset(str(tmp_path / "images"))


# foreground IoU: a perfect prediction scores 1 and an empty one 0, pooled over images; pixels of
# an ignore region count neither way, found or not
def test_foreground_iou_perfect_empty_and_ignored():
    from stackgen.metrics import ForegroundScores

    truth = square(10, 10, 10) | square(30, 5, 8)
    ignore = square(0, 30, 6)
    perfect = ForegroundScores()
    perfect.update(truth | ignore, truth, ignore)
    perfect.update(truth, truth, ignore)
    assert perfect.result()["iou"] == pytest.approx(1.0)
    assert perfect.result()["per_image_iou"] == [1.0, 1.0]
    empty = ForegroundScores()
    empty.update(np.zeros_like(truth), truth, ignore)
    assert empty.result()["iou"] == 0.0
    missed = empty.result()["false_negative"]
    assert sum(missed.values()) == truth.sum()
    # half of one square found, nothing false: 50 of 164 part pixels
    half = ForegroundScores()
    half.update(square(10, 10, 10) & (np.arange(60)[None, :] < 15), truth)
    assert half.result()["iou"] == pytest.approx(50 / truth.sum())


# a false pixel away from the parts is put on what the region map shows there, one next to a part
# on its outline; a missed pixel deep inside a part is "inside parts"
def test_foreground_errors_fall_on_regions_and_outlines():
    from stackgen.metrics import (REGION_BACKGROUND, REGION_FLOOR, REGION_WALLS,
                                  ForegroundScores)

    truth = square(20, 10, 12)
    regions = np.full(truth.shape, REGION_BACKGROUND, np.uint8)
    regions[:, :30] = REGION_FLOOR
    regions[:, 50:] = REGION_WALLS
    predicted = truth.copy()
    predicted[15, 25] = False            # deep inside the part
    predicted[10, 20] = False            # its corner: on the outline
    predicted[35, 5] = True              # the floor, far from the part
    predicted[35, 55] = predicted[36, 55] = True  # the walls
    predicted[5, 40] = True              # neither floor nor walls: the table or background
    predicted[9, 25] = True              # just above the part: its outline
    scores = ForegroundScores(edge_px=2)
    scores.update(predicted, truth, regions=regions)
    result = scores.result()
    assert result["false_negative"]["inside parts"] == 1
    assert result["false_negative"]["edges"] == 1
    assert result["false_positive"] == {"edges": 1, "inside parts": 0, "bin floor": 1,
                                        "bin walls": 2, "table or background": 1, "elsewhere": 0}
    assert result["fp_rate"]["bin walls"] == pytest.approx(2 / (40 * 10))
    # without a region map the same false pixels away from the part are "elsewhere"
    plain = ForegroundScores(edge_px=2)
    plain.update(predicted, truth)
    assert plain.result()["false_positive"]["elsewhere"] == 4
    with pytest.raises(ValueError, match="not one image size"):
        plain.update(predicted, truth[:20])
