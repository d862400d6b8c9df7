"""The quick mode of research/eval-detector: a small segmenter that learns the task to saturation in
minutes on two cores, so that two looks can be told apart.

A fully convolutional network (a four-level U-Net, 8 to 64 channels, 0.12 M weights, unless
eval-detector's --unet-levels says another depth) sees the image at half size and classes every
pixel as background, part interior or part outline (an instance's pixels within 2 pixels of
where it meets another instance or the background). The instances are the connected
interiors, grown back over the outlines next to them; each scores its interior's mean
probability. The scores (stackgen.metrics) are taken at full size against
the exact masks:
foreground IoU (every part pixel against the rest) and the paper's instance MIoU; ignore regions
count neither way. A region map says what each wrong pixel shows (the test set's
regions/*.png, or for stackgen's own scenes the bin's box seen through each pixel).
"""

import math
import os
import time

import cv2
import numpy as np
import torch
from torch import nn
import torch.nn.functional as F

from stackgen.metrics import (REGION_BACKGROUND, REGION_FLOOR, REGION_WALLS,
                              DetectionScores, ForegroundScores)

BACKGROUND, INTERIOR, OUTLINE, IGNORE = 0, 1, 2, 255
# the outline weighs more in the loss: it is a thin class and it alone separates touching parts
CLASS_WEIGHTS = (1.0, 1.0, 3.0)
# the outline's width at the network's size, pixels: wide enough that a gap in it rarely joins
# two touching parts
OUTLINE_PX = 2
# the side of the square crops a step trains on, pixels at the network's size
CROP_PX = 160


# --- labels --------------------------------------------------------------------------------------

def label_map(masks, iscrowd):
    """The instance ids (int32, 0 = no labelled part) and the ignore pixels (bool) of an image's
    COCO masks: real instances 1..K, ignore regions apart."""
    height, width = masks.shape[1:] if len(masks) else (0, 0)
    ids = np.zeros((height, width), np.int32)
    ignore = np.zeros((height, width), bool)
    for k, mask in enumerate(masks):
        if iscrowd[k]:
            ignore |= mask.astype(bool)
        else:
            ids[mask.astype(bool)] = k + 1
    return ids, ignore & (ids == 0)


def sample_at_centres(array, height, width):
    """array (H, W) read at the centres of a (height, width) grid over it (no blending: ids
    stay ids)."""
    rows = np.minimum(((np.arange(height) + 0.5) * array.shape[0] / height).astype(int),
                      array.shape[0] - 1)
    cols = np.minimum(((np.arange(width) + 0.5) * array.shape[1] / width).astype(int),
                      array.shape[1] - 1)
    return array[rows][:, cols]


def class_targets(ids, ignore, height, width, outline_px=OUTLINE_PX):
    """The training target at (height, width): BACKGROUND, INTERIOR, OUTLINE or IGNORE per
    pixel. The outline is an instance's pixels within outline_px (chessboard distance) of the
    nearest of its pixels with a 4-neighbour that is not its own (another instance, an ignore
    region or the background); the image border makes none."""
    small = sample_at_centres(ids, height, width)
    padded = np.pad(small, 1, mode="edge")
    differs = np.zeros(small.shape, bool)
    for dy, dx in ((0, 1), (2, 1), (1, 0), (1, 2)):
        differs |= padded[dy:dy + height, dx:dx + width] != small
    differs &= small > 0
    if outline_px > 1:
        differs = cv2.dilate(differs.astype(np.uint8),
                             np.ones((2 * outline_px - 1,) * 2, np.uint8)).astype(bool)
    target = np.full(small.shape, BACKGROUND, np.uint8)
    target[small > 0] = INTERIOR
    target[(small > 0) & differs] = OUTLINE
    target[sample_at_centres(ignore, height, width) & (small == 0)] = IGNORE
    return target


def load_training_set(dataset, scale, log=None):
    """Every image of a CocoDataset at `scale` (uint8 RGB, area-averaged) with its target."""
    images, targets = [], []
    start = time.monotonic()
    for index in range(len(dataset)):
        image = dataset.image(index)
        height, width = round(image.shape[0] * scale), round(image.shape[1] * scale)
        masks, _, iscrowd = dataset.target(index)
        ids, ignore = label_map(masks, iscrowd) if len(masks) else (
            np.zeros(image.shape[:2], np.int32), np.zeros(image.shape[:2], bool))
        images.append(cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA))
        targets.append(class_targets(ids, ignore, height, width))
        if log and (index + 1) % 100 == 0:
            log("read %d/%d training images (%.0f s)" % (index + 1, len(dataset),
                                                         time.monotonic() - start))
    if len({image.shape for image in images}) > 1:
        raise ValueError("%s: images of several sizes; the quick mode wants one" % dataset.folder)
    return np.stack(images), np.stack(targets)


# --- the network ---------------------------------------------------------------------------------

def _block(inputs, outputs):
    return nn.Sequential(
        nn.Conv2d(inputs, outputs, 3, padding=1, bias=False), nn.BatchNorm2d(outputs),
        nn.ReLU(inplace=True),
        nn.Conv2d(outputs, outputs, 3, padding=1, bias=False), nn.BatchNorm2d(outputs),
        nn.ReLU(inplace=True))


class UNet(nn.Module):
    """A U-Net (Ronneberger et al. 2015) with batch norm and bilinear upsampling, one level per
    entry of `channels`, each level doubling what a pixel sees: (B, 3, H, W) images in 0..1 to
    (B, 3, H, W) class logits; H and W multiples of `multiple`."""

    def __init__(self, channels=(8, 16, 32, 64), classes=3):
        super().__init__()
        c = channels
        self.multiple = 2 ** (len(c) - 1)
        self.down = nn.ModuleList([_block(3, c[0])] +
                                  [_block(c[i - 1], c[i]) for i in range(1, len(c))])
        self.up = nn.ModuleList([_block(c[i] + c[i - 1], c[i - 1])
                                 for i in range(len(c) - 1, 0, -1)])
        self.head = nn.Conv2d(c[0], classes, 1)

    def forward(self, x):
        skips = []
        x = x - 0.5
        for k, block in enumerate(self.down):
            if k:
                x = F.max_pool2d(x, 2)
            x = block(x)
            skips.append(x)
        for block in self.up:
            skips.pop()
            skip = skips[-1]
            x = F.interpolate(x, size=skip.shape[2:], mode="bilinear", align_corners=False)
            x = block(torch.cat([x, skip], dim=1))
        return self.head(x)


def build_model(seed, levels=4):
    """The quick mode's U-Net of `levels` levels, 8 channels doubling per level, its weights
    drawn from `seed`."""
    torch.manual_seed(seed)
    return UNet(channels=tuple(8 * 2 ** k for k in range(levels)))


# --- training ------------------------------------------------------------------------------------

def _batch(images, targets, rng, batch_size, crop):
    """A batch of random crops, flipped and turned by quarter turns at random (the same draws for
    every config with the same seed and set size)."""
    count, height, width = targets.shape
    xs, ys = [], []
    for _ in range(batch_size):
        k = rng.integers(count)
        top = rng.integers(height - crop + 1)
        left = rng.integers(width - crop + 1)
        image = images[k, top:top + crop, left:left + crop]
        target = targets[k, top:top + crop, left:left + crop]
        turns = rng.integers(4)
        image, target = np.rot90(image, turns), np.rot90(target, turns)
        if rng.random() < 0.5:
            image, target = image[:, ::-1], target[:, ::-1]
        xs.append(np.ascontiguousarray(image))
        ys.append(np.ascontiguousarray(target))
    x = torch.from_numpy(np.stack(xs)).permute(0, 3, 1, 2).float() / 255
    return x, torch.from_numpy(np.stack(ys)).long()


def train(model, images, targets, steps, batch_size, crop, lr, seed, log=None):
    """AdamW with a linear warm-up and a cosine decay; the crops, flips and turns come from a
    generator seeded with `seed`. Returns the model (in eval mode) and the last losses."""
    crop = min(crop, targets.shape[1], targets.shape[2]) // model.multiple * model.multiple
    if crop == 0:
        raise RuntimeError("images of %d x %d px at the network's size are smaller than the %d px "
                           "its levels halve" % (targets.shape[2], targets.shape[1],
                                                 model.multiple))
    rng = np.random.default_rng(seed)
    optimizer = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=1e-4)
    weights = torch.tensor(CLASS_WEIGHTS)
    warmup = max(1, min(100, steps // 10))
    model.train()
    start = time.monotonic()
    recent = []
    for step in range(1, steps + 1):
        x, y = _batch(images, targets, rng, batch_size, crop)
        if step <= warmup:
            rate = lr * step / warmup
        else:
            rate = 0.5 * lr * (1 + math.cos(math.pi * (step - warmup) / max(1, steps - warmup)))
        for group in optimizer.param_groups:
            group["lr"] = rate
        loss = F.cross_entropy(model(x), y, weight=weights, ignore_index=IGNORE)
        if not math.isfinite(loss.item()):
            raise RuntimeError("the loss is %s at step %d" % (loss.item(), step))
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        recent = (recent + [loss.item()])[-50:]
        if log and (step % 250 == 0 or step == steps):
            log("step %d/%d, loss %.3f (mean of the last %d), %.2f s per step" % (
                step, steps, sum(recent) / len(recent), len(recent),
                (time.monotonic() - start) / step))
    model.eval()
    return model


# --- prediction ----------------------------------------------------------------------------------

# the quarter turns and mirror images the training draws its crops in: the eight views --tta
# averages
VIEWS = tuple((turns, mirror) for turns in range(4) for mirror in (False, True))


def _probabilities(model, x):
    """The network's softmax (B, 3, H, W) of images x (B, 3, H, W), padded to its multiple (the
    edge pixels repeated) and cut back."""
    height, width = x.shape[2:]
    pad_h, pad_w = -height % model.multiple, -width % model.multiple
    if pad_h or pad_w:
        x = F.pad(x, (0, pad_w, 0, pad_h), mode="replicate")
    return torch.softmax(model(x)[:, :, :height, :width], 1)


def predict(model, image, scale, tta=False):
    """Class probabilities (3, H, W) float32 at the image's full size: the network at `scale`,
    its softmax resized back bilinearly. With tta, the mean of the softmax over the image's
    eight quarter turns and mirror images, each turned back (the same under any of them)."""
    height, width = image.shape[:2]
    small_h, small_w = round(height * scale), round(width * scale)
    small = cv2.resize(image, (small_w, small_h), interpolation=cv2.INTER_AREA)
    x = torch.from_numpy(np.ascontiguousarray(small)).permute(2, 0, 1)[None].float() / 255
    views = VIEWS if tta else VIEWS[:1]
    total = 0
    with torch.no_grad():
        for turns, mirror in views:
            view = torch.rot90(x, turns, (2, 3))
            if mirror:
                view = torch.flip(view, (3,))
            seen = _probabilities(model, view)
            if mirror:
                seen = torch.flip(seen, (3,))
            total = total + torch.rot90(seen, -turns, (2, 3))
        probabilities = F.interpolate(total / len(views), size=(height, width),
                                      mode="bilinear", align_corners=False)
    return probabilities[0].numpy()


def instances(probabilities, min_px=30, grow_px=6):
    """The instances of a prediction: connected interiors (4-connected, at least min_px pixels)
    grown over the foreground next to them by up to grow_px pixels; each scores its interior's
    mean interior probability. Returns (masks (N, H, W) bool, scores (N), foreground (H, W))."""
    classes = probabilities.argmax(0)
    foreground = classes != BACKGROUND
    count, labels, stats, _ = cv2.connectedComponentsWithStats(
        (classes == INTERIOR).astype(np.uint8), connectivity=4)
    keep = np.zeros(count, bool)
    keep[1:] = stats[1:, cv2.CC_STAT_AREA] >= min_px
    labels = np.where(keep[labels], labels, 0).astype(np.int32)
    scores = {k: float(probabilities[INTERIOR][labels == k].mean())
              for k in np.flatnonzero(keep)}
    # the outlines join the interior they touch (the largest id where two meet)
    kernel = np.ones((3, 3), np.uint8)
    for _ in range(grow_px):
        free = foreground & (labels == 0)
        if not free.any():
            break
        grown = cv2.dilate(labels.astype(np.float32), kernel).astype(np.int32)
        labels = np.where(free, grown, labels)
    ids = sorted(scores)
    masks = np.stack([labels == k for k in ids]) if ids else \
        np.zeros((0,) + classes.shape, bool)
    return masks, np.array([scores[k] for k in ids]), foreground


# --- the regions a wrong pixel shows --------------------------------------------------------------

def box_bin_regions(camera, bin_size, height, width):
    """The region map of a box bin seen by a pinhole camera, no parts: each pixel centre's ray
    against the inner floor, the walls (inner faces, rim, outer faces) and nothing else (table
    or background). camera: stackgen-coco's image record camera (fx, fy, cx, cy,
    world_from_camera); bin_size: (inner length, inner width, inner height, wall) in mm; the
    world frame's origin is the centre of the inner floor, z up."""
    length, breadth, depth, wall = bin_size
    pose = camera["world_from_camera"]
    rotation = np.array(pose["rotation"], np.float64).reshape(3, 3)
    eye = np.array(pose["translation_mm"], np.float64)
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    rays = np.stack([(u - camera["cx"]) / camera["fx"], (v - camera["cy"]) / camera["fy"],
                     np.ones_like(u)], axis=-1) @ rotation.T
    nearest = np.full((height, width), np.inf)
    regions = np.full((height, width), REGION_BACKGROUND, np.uint8)
    ax, ay = length / 2, breadth / 2
    bx, by = ax + wall, ay + wall

    def face(axis, value, bounds, code):
        # the rays' hits of the plane coordinate[axis] = value inside the bounds of the others
        direction = rays[..., axis]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (value - eye[axis]) / direction
        hit = eye + rays * t[..., None]
        inside = (t > 0) & np.isfinite(t)
        for other, (low, high) in bounds.items():
            inside &= (hit[..., other] >= low) & (hit[..., other] <= high)
        closer = inside & (t < nearest)
        nearest[closer] = t[closer]
        regions[closer] = code

    face(2, 0.0, {0: (-ax, ax), 1: (-ay, ay)}, REGION_FLOOR)
    for sign in (-1, 1):
        # inner and outer faces of the walls along y and along x
        face(0, sign * ax, {1: (-ay, ay), 2: (0, depth)}, REGION_WALLS)
        face(1, sign * ay, {0: (-ax, ax), 2: (0, depth)}, REGION_WALLS)
        face(0, sign * bx, {1: (-by, by), 2: (-wall, depth)}, REGION_WALLS)
        face(1, sign * by, {0: (-bx, bx), 2: (-wall, depth)}, REGION_WALLS)
    # the rim: the walls' top, between the inner and the outer outline
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (depth - eye[2]) / rays[..., 2]
    hit = eye + rays * t[..., None]
    rim = (t > 0) & (np.abs(hit[..., 0]) <= bx) & (np.abs(hit[..., 1]) <= by) & \
        ~((np.abs(hit[..., 0]) < ax) & (np.abs(hit[..., 1]) < ay)) & (t < nearest)
    regions[rim] = REGION_WALLS
    return regions


def dataset_regions(dataset, index, bin_size=None):
    """The region map of an image: the set's regions/<image name>.png where it has one, else,
    where the image record holds the camera (stackgen-coco's, research/make-blender-testset's), the
    box bin of the record's bin_size_mm or of bin_size; else None."""
    record = dataset.images[index]
    stem = os.path.splitext(os.path.basename(record["file_name"]))[0]
    path = os.path.join(dataset.folder, "regions", stem + ".png")
    if os.path.isfile(path):
        regions = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
        if regions is None or regions.shape != (record["height"], record["width"]):
            raise ValueError("%s: not a %d x %d region map" % (path, record["width"],
                                                               record["height"]))
        return regions
    camera = record.get("stackgen", {}).get("camera")
    bin_size = record.get("stackgen", {}).get("bin_size_mm", bin_size)
    if camera is None or bin_size is None:
        return None
    return box_bin_regions(camera, bin_size, record["height"], record["width"])


# --- scoring -------------------------------------------------------------------------------------

def score(model, dataset, scale, bin_size=None, worst=0, tta=False):
    """Scores a trained model on a CocoDataset (with tta, its predictions averaged over each
    image's eight views): (ForegroundScores result, DetectionScores result, the `worst` images'
    pictures of their errors, worst first)."""
    pixels = ForegroundScores()
    detections = DetectionScores()
    pictures = []
    for index in range(len(dataset)):
        image = dataset.image(index)
        masks, _, iscrowd = dataset.target(index)
        probabilities = predict(model, image, scale, tta)
        found, scores, foreground = instances(probabilities)
        ids, ignore = label_map(masks, iscrowd) if len(masks) else (
            np.zeros(image.shape[:2], np.int32), np.zeros(image.shape[:2], bool))
        regions = dataset_regions(dataset, index, bin_size)
        pixels.update(foreground, ids > 0, ignore, regions)
        detections.update(scores, found, masks.astype(bool) if len(masks) else
                          np.zeros((0,) + image.shape[:2], bool), iscrowd)
        if worst:
            pictures.append((pixels.result()["per_image_iou"][-1], index,
                             error_picture(image, foreground, ids > 0, ignore)))
            pictures = sorted(pictures, key=lambda p: p[0])[:worst]
    return pixels.result(), detections.result(), pictures


def error_picture(image, predicted, truth, ignore):
    """The image (RGB) darkened, with the parts found in green, the false pixels in red, the
    missed ones in blue and the ignore regions in grey; returned as BGR for cv2.imwrite."""
    picture = (image.astype(np.float32) * 0.45).astype(np.uint8)
    colours = [(predicted & truth & ~ignore, (60, 200, 60)),
               (predicted & ~truth & ~ignore, (235, 40, 40)),
               (~predicted & truth & ~ignore, (40, 110, 255)),
               (ignore, (150, 150, 150))]
    for mask, colour in colours:
        picture[mask] = (0.35 * picture[mask] + 0.65 * np.array(colour)).astype(np.uint8)
    return cv2.cvtColor(picture, cv2.COLOR_RGB2BGR)
