"""Detection scores for instance masks: the seed paper's MIoU and COCO mask AP (stackgen.metrics).

- The paper's score (Zhang et al. 2021, Table 1): predictions above a score threshold are matched
  greedily, highest score first, to ground-truth masks with mask IoU > 0.6. A match is a true
  positive, an unmatched prediction a false positive, an unmatched ground truth a false negative;
  the score ("MIoU") is TP / (TP + FP + FN). Ignore regions (COCO iscrowd 1: objects too hidden
  to label) are neither: a prediction that covers one (intersection over the prediction's own
  area above the threshold) is dropped, and they are never missed.
- COCO mask AP as cocodataset/cocoapi's COCOeval computes it for one category (segm, all areas,
  100 detections per image): per IoU threshold 0.50, 0.55, ..., 0.95 the same greedy matching,
  crowd regions matched by intersection over the detection's area and their detections ignored,
  precision made monotone and read at 101 recall points; AP is the mean over thresholds, AP50 and
  AP75 single thresholds.

- Foreground IoU of a part / not-part segmentation (ForegroundScores): intersection over union
  of the pixels, pooled over the images, ignore regions neither; and where the wrong pixels lie
  (along the parts' outlines, inside parts, on the bin floor, the bin walls, the table or
  background), so a change can be aimed at a cause.

- COCO box AP the same way on boxes (cocoapi's bbox IoU: XYXY, no pixel added; a crowd region
  again by intersection over the detection's box), when the predictions' boxes are given; the
  ground truth's boxes are the extents of its masks unless given.

Masks are boolean or 0/1 arrays (numpy, or anything np.asarray takes, such as CPU tensors).
"""

from typing import Dict, Optional

import numpy as np

__all__ = ["mask_iou", "box_iou", "mask_boxes", "DetectionScores", "ForegroundScores",
           "PAPER_IOU", "COCO_IOUS", "REGION_BACKGROUND", "REGION_FLOOR", "REGION_WALLS",
           "REGION_UNKNOWN"]

PAPER_IOU = 0.6
COCO_IOUS = np.linspace(0.5, 0.95, 10)

# what a pixel shows where no part is, in a region map (uint8): the table or whatever is around
# the bin, the bin's floor, its walls and rim; unknown where a test set says nothing
REGION_BACKGROUND = 0
REGION_FLOOR = 1
REGION_WALLS = 2
REGION_UNKNOWN = 255
_REGION_NAMES = {REGION_FLOOR: "bin floor", REGION_WALLS: "bin walls",
                 REGION_BACKGROUND: "table or background"}


def mask_iou(predicted: np.ndarray, truth: np.ndarray,
             crowd: Optional[np.ndarray] = None) -> np.ndarray:
    """The IoU of predicted and ground-truth masks.

    For a ground truth marked in `crowd` the value is the intersection over the prediction's
    area, as cocoapi does for iscrowd regions.

    Args:
        predicted: (N, H, W) the predicted masks.
        truth: (M, H, W) the ground-truth masks.
        crowd: (M) booleans, the ground truths that are iscrowd regions; default none.

    Returns:
        (N, M) float64 IoU.

    Raises:
        ValueError: the predicted and ground-truth masks are not the same image size.
    """
    predicted = np.asarray(predicted).astype(bool)
    truth = np.asarray(truth).astype(bool)
    n, m = len(predicted), len(truth)
    if n == 0 or m == 0:
        return np.zeros((n, m))
    if predicted.shape[1:] != truth.shape[1:]:
        raise ValueError("predicted masks are %s, ground truth %s: not the same image size" %
                         (predicted.shape[1:], truth.shape[1:]))
    p = predicted.reshape(n, -1).astype(np.float32)
    t = truth.reshape(m, -1).astype(np.float32)
    intersection = p @ t.T
    p_area = p.sum(axis=1)[:, None]
    union = p_area + t.sum(axis=1)[None, :] - intersection
    iou = np.divide(intersection, union, out=np.zeros_like(intersection), where=union > 0)
    if crowd is not None:
        crowd = np.asarray(crowd, dtype=bool)
        covered = np.divide(intersection, p_area, out=np.zeros_like(intersection),
                            where=p_area > 0)
        iou[:, crowd] = covered[:, crowd]
    return iou.astype(np.float64)


def box_iou(predicted: np.ndarray, truth: np.ndarray,
            crowd: Optional[np.ndarray] = None) -> np.ndarray:
    """The IoU of predicted and ground-truth boxes, as cocoapi computes it.

    Areas are (x1 - x0) (y1 - y0); for a ground truth marked in `crowd` the value is the
    intersection over the prediction's area.

    Args:
        predicted: (N, 4) XYXY, the predicted boxes.
        truth: (M, 4) XYXY, the ground-truth boxes.
        crowd: (M) booleans, the ground truths that are iscrowd regions; default none.

    Returns:
        (N, M) float64 IoU.
    """
    p = np.asarray(predicted, dtype=np.float64).reshape(-1, 4)
    t = np.asarray(truth, dtype=np.float64).reshape(-1, 4)
    if len(p) == 0 or len(t) == 0:
        return np.zeros((len(p), len(t)))
    width = np.clip(np.minimum(p[:, None, 2], t[None, :, 2]) -
                    np.maximum(p[:, None, 0], t[None, :, 0]), 0, None)
    height = np.clip(np.minimum(p[:, None, 3], t[None, :, 3]) -
                     np.maximum(p[:, None, 1], t[None, :, 1]), 0, None)
    intersection = width * height
    p_area = ((p[:, 2] - p[:, 0]) * (p[:, 3] - p[:, 1]))[:, None]
    t_area = ((t[:, 2] - t[:, 0]) * (t[:, 3] - t[:, 1]))[None, :]
    union = p_area + t_area - intersection
    iou = np.divide(intersection, union, out=np.zeros_like(intersection), where=union > 0)
    if crowd is not None:
        crowd = np.asarray(crowd, dtype=bool)
        covered = np.divide(intersection, np.broadcast_to(p_area, intersection.shape),
                            out=np.zeros_like(intersection), where=p_area > 0)
        iou[:, crowd] = covered[:, crowd]
    return iou


def mask_boxes(masks: np.ndarray) -> np.ndarray:
    """The extents of masks as boxes.

    Args:
        masks: (K, H, W) the masks.

    Returns:
        (K, 4) float64 XYXY extents (pixel edges); zeros for an empty mask.
    """
    masks = np.asarray(masks).astype(bool)
    boxes = np.zeros((len(masks), 4))
    for k, mask in enumerate(masks):
        ys, xs = np.nonzero(mask)
        if len(xs):
            boxes[k] = [xs.min(), ys.min(), xs.max() + 1, ys.max() + 1]
    return boxes


def _match(iou, crowd, threshold, strict):
    """cocoapi's greedy matching of detections (rows, best score first) to ground truths (columns,
    crowd last): for each detection the best still-free ground truth at or above (strictly above
    with `strict`) the threshold, a crowd region reusable and taken only when no real one
    matches. Returns per detection: matched a real ground truth, matched a crowd region; and per
    real ground truth whether it was matched."""
    n, m = iou.shape
    order = np.argsort(crowd, kind="stable")  # real ground truths first, as cocoapi sorts them
    iou = iou[:, order]
    crowd = crowd[order]
    taken = np.zeros(m, dtype=bool)
    matched = np.zeros(n, dtype=bool)
    to_crowd = np.zeros(n, dtype=bool)
    for d in range(n):
        best = -1
        best_iou = threshold
        for g in range(m):
            if taken[g] and not crowd[g]:
                continue
            if best >= 0 and not crowd[best] and crowd[g]:
                break  # a real match beats any crowd region
            value = iou[d, g]
            if value < best_iou or (strict and value <= threshold):
                continue
            best, best_iou = g, value
        if best < 0:
            continue
        taken[best] = True
        if crowd[best]:
            to_crowd[d] = True
        else:
            matched[d] = True
    real_taken = np.zeros(m, dtype=bool)
    real_taken[order] = taken & ~crowd
    return matched, to_crowd, real_taken


class DetectionScores:
    """Accumulates predictions and ground truth image by image; result() gives the paper's MIoU
    (with its TP, FP, FN), COCO mask AP, AP50, AP75 and, when every image's predicted boxes were
    given, COCO box AP.

    Args:
        paper_iou: the paper's match threshold (a match needs mask IoU above it; 0.6).
        score_threshold: predictions below it do not count for the paper's score (they do for
            AP, as in COCO).
        max_detections: the highest-scoring predictions kept per image (COCO's 100).

    Raises:
        ValueError: paper_iou is not in (0, 1).
    """

    def __init__(self, paper_iou: float = PAPER_IOU, score_threshold: float = 0.5,
                 max_detections: int = 100) -> None:
        if not 0 < paper_iou < 1:
            raise ValueError("paper_iou wants a number in (0, 1), got %r" % paper_iou)
        self.paper_iou = paper_iou
        self.score_threshold = score_threshold
        self.max_detections = max_detections
        self.tp = self.fp = self.fn = 0
        self.images = 0
        self._real_truths = 0
        self._scores = []
        self._matched = [[] for _ in COCO_IOUS]  # per threshold: per detection, a true positive
        self._ignored = [[] for _ in COCO_IOUS]  # per threshold: per detection, on a crowd region
        self._box_images = 0
        self._box_matched = [[] for _ in COCO_IOUS]
        self._box_ignored = [[] for _ in COCO_IOUS]

    def update(self, scores: np.ndarray, masks: np.ndarray, truth_masks: np.ndarray,
               truth_crowd: Optional[np.ndarray] = None, boxes: Optional[np.ndarray] = None,
               truth_boxes: Optional[np.ndarray] = None) -> None:
        """Adds one image.

        Args:
            scores: (N) the predictions' scores.
            masks: (N, H, W) their masks, booleans or probabilities already thresholded.
            truth_masks: (M, H, W) the ground truth's visible masks.
            truth_crowd: (M) booleans, iscrowd (ignore regions); default none.
            boxes: (N, 4) XYXY, the predictions' boxes, for box AP; default none.
            truth_boxes: (M, 4) XYXY, the ground truth's boxes; default the masks' extents.

        Raises:
            ValueError: the counts or image sizes do not agree.
        """
        scores = np.asarray(scores, dtype=np.float64).reshape(-1)
        masks = np.asarray(masks)
        truth_masks = np.asarray(truth_masks)
        if len(masks) != len(scores):
            raise ValueError("%d masks for %d scores" % (len(masks), len(scores)))
        if boxes is not None:
            boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
            if len(boxes) != len(scores):
                raise ValueError("%d boxes for %d scores" % (len(boxes), len(scores)))
        if boxes is not None:
            truth_boxes = (mask_boxes(truth_masks) if truth_boxes is None else
                           np.asarray(truth_boxes, dtype=np.float64).reshape(-1, 4))
            if len(truth_boxes) != len(truth_masks):
                raise ValueError("%d ground-truth boxes for %d masks" % (len(truth_boxes),
                                                                        len(truth_masks)))
        crowd = (np.zeros(len(truth_masks), dtype=bool) if truth_crowd is None
                 else np.asarray(truth_crowd, dtype=bool).reshape(-1))
        if len(crowd) != len(truth_masks):
            raise ValueError("%d crowd flags for %d ground-truth masks" % (len(crowd),
                                                                          len(truth_masks)))
        # the best-scoring detections, best first
        order = np.argsort(-scores, kind="stable")[: self.max_detections]
        scores = scores[order]
        masks = masks[order] if len(order) else masks[:0]
        iou = mask_iou(masks, truth_masks, crowd) if len(masks) and len(truth_masks) else \
            np.zeros((len(masks), len(truth_masks)))
        self.images += 1
        real = int((~crowd).sum())
        self._real_truths += real

        # the paper's score: confident predictions, IoU strictly above the threshold
        confident = scores >= self.score_threshold
        matched, to_crowd, taken = _match(iou[confident], crowd, self.paper_iou, strict=True)
        self.tp += int(matched.sum())
        self.fp += int((~matched & ~to_crowd).sum())
        self.fn += real - int(taken.sum())

        # COCO: every kept detection, each threshold
        self._scores.append(scores)
        for k, threshold in enumerate(COCO_IOUS):
            matched, to_crowd, _ = _match(iou, crowd, threshold, strict=False)
            self._matched[k].append(matched)
            self._ignored[k].append(to_crowd)
        if boxes is None:
            return
        box_iou_matrix = box_iou(boxes[order], truth_boxes, crowd)
        self._box_images += 1
        for k, threshold in enumerate(COCO_IOUS):
            matched, to_crowd, _ = _match(box_iou_matrix, crowd, threshold, strict=False)
            self._box_matched[k].append(matched)
            self._box_ignored[k].append(to_crowd)

    def _average_precision(self, matched, ignored):
        if self._real_truths == 0:
            return float("nan")
        scores = np.concatenate(self._scores) if self._scores else np.zeros(0)
        order = np.argsort(-scores, kind="mergesort")
        matched = np.concatenate(matched)[order] if self._scores else np.zeros(0, bool)
        ignored = np.concatenate(ignored)[order] if self._scores else np.zeros(0, bool)
        matched = matched[~ignored]
        tp = np.cumsum(matched)
        fp = np.cumsum(~matched)
        recall = tp / self._real_truths
        precision = tp / np.maximum(tp + fp, np.finfo(np.float64).eps)
        # monotone precision, read at 101 recall points
        for i in range(len(precision) - 1, 0, -1):
            precision[i - 1] = max(precision[i - 1], precision[i])
        points = np.linspace(0, 1, 101)
        indices = np.searchsorted(recall, points, side="left")
        read = np.array([precision[i] if i < len(precision) else 0.0 for i in indices])
        return float(read.mean())

    def result(self) -> Dict[str, float]:
        """The scores so far.

        Returns:
            A dict: miou (the paper's TP / (TP + FP + FN)), tp, fp, fn, ap, ap50, ap75 (mask AP;
            NaN when no image had a real ground truth), images; and box_ap, box_ap50,
            box_ap75 when every image came with its predicted boxes.
        """
        counted = self.tp + self.fp + self.fn
        per_threshold = [self._average_precision(self._matched[k], self._ignored[k])
                         for k in range(len(COCO_IOUS))]
        result = {"miou": self.tp / counted if counted else float("nan"),
                  "tp": self.tp, "fp": self.fp, "fn": self.fn,
                  "ap": float(np.mean(per_threshold)), "ap50": per_threshold[0],
                  "ap75": per_threshold[5], "images": self.images}
        if self.images and self._box_images == self.images:
            boxes = [self._average_precision(self._box_matched[k], self._box_ignored[k])
                     for k in range(len(COCO_IOUS))]
            result.update(box_ap=float(np.mean(boxes)), box_ap50=boxes[0], box_ap75=boxes[5])
        return result


def _grow(mask: np.ndarray, radius: int) -> np.ndarray:
    """The pixels within `radius` (chessboard distance) of a True pixel of mask."""
    grown = mask.copy()
    height, width = mask.shape
    for dy in range(-radius, radius + 1):
        for dx in range(-radius, radius + 1):
            if dy == 0 and dx == 0:
                continue
            grown[max(dy, 0):height + min(dy, 0), max(dx, 0):width + min(dx, 0)] |= \
                mask[max(-dy, 0):height + min(-dy, 0), max(-dx, 0):width + min(-dx, 0)]
    return grown


class ForegroundScores:
    """Accumulates a part / not-part segmentation image by image; result() gives the foreground
    IoU pooled over the images (every image's intersection and union summed) and where the wrong
    pixels lie.

    A wrong pixel within `edge_px` of the outline between parts and the rest (either side) is
    an edge error; further from it a missed pixel lies inside a part, and a false one on what the
    region map says is there (bin floor, bin walls, table or background; "elsewhere" without a
    map). Ignore regions (parts too hidden to label) count neither way.

    Args:
        edge_px: the width of the band along the outlines, pixels (2).
    """

    CAUSES = ("edges", "inside parts", "bin floor", "bin walls", "table or background",
              "elsewhere")

    def __init__(self, edge_px: int = 2) -> None:
        if edge_px < 0:
            raise ValueError("edge_px wants a whole number >= 0, got %r" % edge_px)
        self.edge_px = edge_px
        self.intersection = self.union = 0
        self.false_positive = {cause: 0 for cause in self.CAUSES}
        self.false_negative = {cause: 0 for cause in self.CAUSES}
        self.region_pixels = {name: 0 for name in _REGION_NAMES.values()}
        self.per_image = []  # (intersection, union) of each image, in order

    def update(self, predicted: np.ndarray, truth: np.ndarray,
               ignore: Optional[np.ndarray] = None, regions: Optional[np.ndarray] = None) -> None:
        """Adds one image.

        Args:
            predicted: (H, W) booleans, the pixels predicted to be part.
            truth: (H, W) booleans, the pixels that are part (any labelled instance).
            ignore: (H, W) booleans, pixels that count neither way (ignore regions); default
                none.
            regions: (H, W) uint8 region map (REGION_*), what is seen where no part is; default
                none (false pixels away from the outlines are "elsewhere").

        Raises:
            ValueError: the arrays are not all of one image size.
        """
        predicted = np.asarray(predicted).astype(bool)
        truth = np.asarray(truth).astype(bool)
        shapes = {predicted.shape, truth.shape}
        if ignore is not None:
            ignore = np.asarray(ignore).astype(bool)
            shapes.add(ignore.shape)
        if regions is not None:
            regions = np.asarray(regions)
            shapes.add(regions.shape)
        if len(shapes) != 1 or predicted.ndim != 2:
            raise ValueError("predicted %s, truth %s%s%s: not one image size" % (
                predicted.shape, truth.shape,
                "" if ignore is None else ", ignore %s" % (ignore.shape,),
                "" if regions is None else ", regions %s" % (regions.shape,)))
        counted = np.ones_like(truth) if ignore is None else ~ignore
        intersection = int((predicted & truth & counted).sum())
        union = int(((predicted | truth) & counted).sum())
        self.intersection += intersection
        self.union += union
        self.per_image.append((intersection, union))

        # where the wrong pixels lie: along the outlines, else inside parts or on a region
        edges = _grow(truth, self.edge_px) & _grow(~truth, self.edge_px)
        missed = truth & ~predicted & counted
        false = predicted & ~truth & counted
        self.false_negative["edges"] += int((missed & edges).sum())
        self.false_negative["inside parts"] += int((missed & ~edges).sum())
        self.false_positive["edges"] += int((false & edges).sum())
        away = false & ~edges
        if regions is None:
            self.false_positive["elsewhere"] += int(away.sum())
            return
        known = np.zeros_like(away)
        for code, name in _REGION_NAMES.items():
            region = regions == code
            known |= region
            self.false_positive[name] += int((away & region).sum())
            self.region_pixels[name] += int((region & ~truth & counted).sum())
        self.false_positive["elsewhere"] += int((away & ~known).sum())

    def result(self) -> Dict[str, object]:
        """The scores so far.

        Returns:
            A dict: iou (pooled; NaN before any pixel was counted), intersection, union, images,
            false_positive and false_negative (pixels per cause, CAUSES), fp_rate (per region
            of the map: its false pixels over its pixels not part), and per_image_iou (each
            image's own IoU, 1 for an image with nothing to find and nothing found).
        """
        rates = {name: (self.false_positive[name] / pixels if pixels else float("nan"))
                 for name, pixels in self.region_pixels.items()}
        return {"iou": self.intersection / self.union if self.union else float("nan"),
                "intersection": self.intersection, "union": self.union,
                "images": len(self.per_image),
                "false_positive": dict(self.false_positive),
                "false_negative": dict(self.false_negative),
                "fp_rate": rates,
                "per_image_iou": [i / u if u else 1.0 for i, u in self.per_image]}
