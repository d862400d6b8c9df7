"""Training-time augmentation with exact labels (the paper's flip, crop, zoom, affine transform,
random erasure, brightness and contrast).

Every geometric change is one affine map A of the image plane (crop, zoom, rotation, shear,
translation and flips composed). The image is resampled bilinearly; the instance map, the depth
and each object's full (amodal) mask are resampled by nearest neighbour through the same pixel
map, so every label value is a label value of the scene, never a blend. The labels are then
computed again from the transformed maps, not transformed themselves:

- visible mask = the pixels of the transformed instance map that hold the object's id (after
  erasure, which hides what lies under the erased rectangle, as an occluder would);
- box = the extent of that mask (XYXY, pixel edges);
- px_count_all = the pixels of the transformed full mask, counted on a canvas that reaches past
  the image where the object does, so an object cut by a crop keeps its whole size; for an
  object the scene's own image edge already cut (its px_count_all counts pixels its full mask,
  which covers the image only, does not hold), those pixels are added scaled by the map's area
  factor |det A|, their count after any affine map up to rounding at the outline;
- visib_fract = visible pixels / px_count_all: cropping or erasing part of an object lowers it;
- an object the generator annotated stays annotated while visib_fract >= min_visib_fract;
  below it, or when the generator marked it ignored, it is an ignore region (iscrowd 1); with no
  visible pixel left it is gone. Objects the generator dropped stay dropped.
- K becomes A @ K (a general 3x3 matrix after rotation or shear): poses stay in the camera frame
  and still project onto the transformed image through it; depth stays z in millimetres.

A flip mirrors the image of a chiral part: right for detection and masks, but no rigid pose
explains it; turn flips and the affine part off to train pose estimators on K.

Every draw comes from the generator `rng` passed in (StreamDataset seeds it from its seed and the
scene's generator id, seq and use), a fixed number of draws per lever, so the same scene and seed
give the same result.
"""

import math

import cv2
import numpy as np

__all__ = ["Augment", "exact_labels"]


def _uniform(u, low, high):
    return low + (high - low) * u


def _log_uniform(u, low, high):
    return math.exp(_uniform(u, math.log(low), math.log(high)))


def _check_range(name, value, low, high):
    try:
        a, b = value
    except (TypeError, ValueError):
        raise ValueError("%s must be a (min, max) pair, got %r" % (name, value)) from None
    if not (low <= a <= b <= high):
        raise ValueError("%s must satisfy %g <= min <= max <= %g, got %r" %
                         (name, low, high, value))
    return float(a), float(b)


def _check_number(name, value, low, high):
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not low <= value <= high:
        raise ValueError("%s must be a number in [%g, %g], got %r" % (name, low, high, value))
    return float(value)


def _check_fraction(name, value):
    if not isinstance(value, (int, float)) or not 0 <= value <= 1:
        raise ValueError("%s must be a probability in [0, 1], got %r" % (name, value))
    return float(value)


def exact_labels(instance_map, instance_ids, px_count_all, annotated, ignored, min_visib_fract,
                 regions=None, min_visible_px=1):
    """Labels of the candidate instances computed from an instance map.

    The candidates are the instances the generator annotated or ignored.

    Args:
        instance_map: (H, W) the instance map.
        instance_ids: (N,) the candidates' ids in the instance map.
        px_count_all: (N,) the candidates' full (amodal) pixel counts.
        annotated: (N,) booleans, the candidates the generator annotated.
        ignored: (N,) booleans, the candidates the generator marked ignored.
        min_visib_fract: an annotated instance less visible than this is an ignore region.
        regions: (N, 4) x0, y0, x1, y1 (exclusive) bound where each instance's pixels can be
            (Augment gives them); without them the whole map is searched.
        min_visible_px: an annotated instance with fewer visible pixels is an ignore region, as
            the generator's annotation.min_visible_px (default 1).

    Returns:
        A dict with `keep` (indices into the inputs of the instances that have a visible
        pixel), `masks` (K, H, W) uint8 visible masks, `boxes` (K, 4) float32 XYXY,
        `px_count_visib` (K,), `px_count_all` (K,), `visib_fract` (K,) float64 (px_count_visib
        / px_count_all) and `iscrowd` (K,) int64 (0: annotated, at least min_visib_fract
        visible and at least min_visible_px pixels, as the generator's
        annotation.min_visible_px; 1: an ignore region).
    """
    height, width = instance_map.shape
    count = len(instance_ids)
    if regions is None:
        regions = np.tile(np.array([0, 0, width, height], dtype=np.int64), (count, 1))
    counts = np.zeros(count, dtype=np.int64)
    boxes = np.zeros((count, 4), dtype=np.float32)
    inside = []
    for k in range(count):
        x0, y0, x1, y1 = (int(v) for v in regions[k])
        mask = np.equal(instance_map[y0:y1, x0:x1], instance_ids[k]).view(np.uint8)
        inside.append(mask)
        counts[k] = cv2.countNonZero(mask) if mask.size else 0
        if counts[k]:
            x, y, w, h = cv2.boundingRect(mask)
            boxes[k] = (x0 + x, y0 + y, x0 + x + w, y0 + y + h)
    keep = np.flatnonzero(counts > 0)
    masks = np.zeros((len(keep), height, width), dtype=np.uint8)
    for row, k in enumerate(keep):
        x0, y0, x1, y1 = (int(v) for v in regions[k])
        masks[row, y0:y1, x0:x1] = inside[k]
    px_all = np.asarray(px_count_all, dtype=np.int64)[keep]
    visib = np.where(px_all > 0, counts[keep] / np.maximum(px_all, 1), 0.0)
    # an object the generator annotated stays annotated while visible enough
    good = (np.asarray(annotated, dtype=bool)[keep] & (visib >= min_visib_fract) &
            (counts[keep] >= max(1, min_visible_px)))
    return {
        "keep": keep,
        "masks": masks,
        "boxes": boxes[keep],
        "px_count_visib": counts[keep],
        "px_count_all": px_all,
        "visib_fract": visib,
        "iscrowd": (~good).astype(np.int64),
    }


def _moved_box(a, box, width, height, clip):
    """The pixel rectangle x0, y0, x1, y1 (exclusive) that holds the image under `a` of the
    pixels of `box` (x, y, w, h), with a pixel of margin; clipped to the image when `clip`."""
    bx, by, bw, bh = box
    corners = np.array([[bx - 0.5, by - 0.5, 1], [bx + bw - 0.5, by - 0.5, 1],
                        [bx - 0.5, by + bh - 0.5, 1], [bx + bw - 0.5, by + bh - 0.5, 1]]) @ a.T
    x0 = int(math.floor(corners[:, 0].min())) - 1
    x1 = int(math.ceil(corners[:, 0].max())) + 2
    y0 = int(math.floor(corners[:, 1].min())) - 1
    y1 = int(math.ceil(corners[:, 1].max())) + 2
    if clip:
        x0, x1 = min(max(x0, 0), width), min(max(x1, 0), width)
        y0, y1 = min(max(y0, 0), height), min(max(y1, 0), height)
    return x0, y0, x1, y1


class Augment:
    """The paper's training-time augmentations, with exact labels.

    Applied to image, instance map, depth and masks together, with the labels computed again
    from the result (see the module text).

    Args:
        hflip: probability of a horizontal flip (default 0.5).
        vflip: probability of a vertical flip (default 0).
        crop: probability of a crop (default 0.5), at a random place, scaled back to the image
            size (a zoom in).
        crop_scale: the crop's side as a fraction of the image's, (min, max) (default 0.6..1).
        zoom: probability of a zoom about the centre (default 0.5).
        zoom_range: the zoom factor, (min, max), drawn log-uniformly (default 0.8..1.25; below 1
            leaves a black border).
        affine: probability of an affine transform about the centre (default 0.5): rotation,
            shear and translation.
        rotate_deg: the largest rotation in degrees (default 10).
        shear_deg: the largest shear in degrees (default 5).
        translate: the largest translation as a fraction of the size (default 0.05).
        erase: probability of a random erasure (default 0.5): a rectangle of the image filled
            with noise; depth there becomes 0 (no depth) and the instance map background.
        erase_area: the rectangle's area as a fraction of the image's, (min, max) (default
            0.02..0.2).
        erase_aspect: the rectangle's aspect ratio, (min, max), drawn log-uniformly (default
            0.3..3.3).
        brightness: the largest brightness change, drawn uniformly in +-that (default 0.2: up
            to +-20 % of full scale).
        contrast: the largest contrast change, drawn uniformly in +-that (default 0.2: a factor
            0.8..1.2 about the mean).

    Raises:
        ValueError: a probability or change outside [0, 1], a range that is not a (min, max)
            pair within its bounds, or a number outside its bounds.
    """

    def __init__(self, hflip=0.5, vflip=0.0, crop=0.5, crop_scale=(0.6, 1.0), zoom=0.5,
                 zoom_range=(0.8, 1.25), affine=0.5, rotate_deg=10.0, shear_deg=5.0,
                 translate=0.05, erase=0.5, erase_area=(0.02, 0.2), erase_aspect=(0.3, 3.3),
                 brightness=0.2, contrast=0.2):
        self.hflip = _check_fraction("hflip", hflip)
        self.vflip = _check_fraction("vflip", vflip)
        self.crop = _check_fraction("crop", crop)
        self.crop_scale = _check_range("crop_scale", crop_scale, 0.05, 1.0)
        self.zoom = _check_fraction("zoom", zoom)
        self.zoom_range = _check_range("zoom_range", zoom_range, 0.1, 10.0)
        self.affine = _check_fraction("affine", affine)
        self.rotate_deg = _check_number("rotate_deg", rotate_deg, 0, 180)
        self.shear_deg = _check_number("shear_deg", shear_deg, 0, 45)
        self.translate = _check_number("translate", translate, 0, 0.5)
        self.erase = _check_fraction("erase", erase)
        self.erase_area = _check_range("erase_area", erase_area, 0.0, 1.0)
        self.erase_aspect = _check_range("erase_aspect", erase_aspect, 0.01, 100.0)
        self.brightness = _check_fraction("brightness", brightness)
        self.contrast = _check_fraction("contrast", contrast)
        self._grids = {}

    def __repr__(self):
        fields = ("hflip", "vflip", "crop", "crop_scale", "zoom", "zoom_range", "affine",
                  "rotate_deg", "shear_deg", "translate", "erase", "erase_area", "erase_aspect",
                  "brightness", "contrast")
        return "Augment(%s)" % ", ".join("%s=%r" % (f, getattr(self, f)) for f in fields)

    def draw_affine(self, rng, width, height):
        """Draws the geometric part of one augmentation.

        Takes 13 draws from `rng` whatever is switched on.

        Args:
            rng: the numpy random generator to draw from.
            width: the image's width in pixels.
            height: the image's height in pixels.

        Returns:
            The 3x3 matrix A (destination pixel = A @ source pixel, pixel centres at integers).
        """
        u = rng.random(13)
        a = np.eye(3)
        cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
        centre = np.array([[1, 0, cx], [0, 1, cy], [0, 0, 1.0]])
        uncentre = np.array([[1, 0, -cx], [0, 1, -cy], [0, 0, 1.0]])
        # crop: a window of side s at a random place, scaled up to the whole image
        if u[0] < self.crop:
            s = _uniform(u[1], *self.crop_scale)
            x0 = u[2] * (1 - s) * width
            y0 = u[3] * (1 - s) * height
            # source (x0 + (x + 0.5) s - 0.5) goes to destination x
            a = np.array([[1 / s, 0, (0.5 - x0) / s - 0.5], [0, 1 / s, (0.5 - y0) / s - 0.5],
                          [0, 0, 1.0]]) @ a
        # zoom about the centre
        if u[4] < self.zoom:
            z = _log_uniform(u[5], *self.zoom_range)
            a = centre @ np.diag([z, z, 1.0]) @ uncentre @ a
        # rotation, shear and translation about the centre
        if u[6] < self.affine:
            angle = math.radians(_uniform(u[7], -self.rotate_deg, self.rotate_deg))
            shear = math.radians(_uniform(u[8], -self.shear_deg, self.shear_deg))
            tx = _uniform(u[9], -self.translate, self.translate) * width
            ty = _uniform(u[10], -self.translate, self.translate) * height
            rotation = np.array([[math.cos(angle), -math.sin(angle), 0],
                                 [math.sin(angle), math.cos(angle), 0], [0, 0, 1.0]])
            shearing = np.array([[1, math.tan(shear), 0], [0, 1, 0], [0, 0, 1.0]])
            moving = np.array([[1, 0, tx], [0, 1, ty], [0, 0, 1.0]])
            a = moving @ centre @ rotation @ shearing @ uncentre @ a
        # flips
        flip = np.eye(3)
        if u[11] < self.hflip:
            flip = np.array([[-1, 0, width - 1], [0, 1, 0], [0, 0, 1.0]]) @ flip
        if u[12] < self.vflip:
            flip = np.array([[1, 0, 0], [0, -1, height - 1], [0, 0, 1.0]]) @ flip
        return flip @ a

    def _maps(self, inverse, x0, x1, y0, y1):
        # where destination pixels x0..x1-1, y0..y1-1 come from, in float32; the same
        # destination pixel gets the same value whatever the window, so the full image and the
        # canvases of single objects sample alike
        xs = np.arange(x0, x1, dtype=np.float32)[None, :]
        ys = np.arange(y0, y1, dtype=np.float32)[:, None]
        coefficients = inverse.astype(np.float32)
        map_x = coefficients[0, 0] * xs + (coefficients[0, 1] * ys + coefficients[0, 2])
        map_y = coefficients[1, 0] * xs + (coefficients[1, 1] * ys + coefficients[1, 2])
        return map_x, map_y

    def _move_px_count_all(self, sample, a, inverse, width, height, px_all):
        """Each full mask on a canvas that holds all of the object moved by `a`, in or out of
        the image: its pixels there are the object's px_count_all now (set in `px_all`). Each
        mask comes within its box, so the maps are shifted by the box's corner, rounded down to
        even numbers: the shift is exact in float32 for the source pixels near the box, the only
        ones that matter, and keeps OpenCV's rounding of x.5 to the even neighbour where it
        was."""
        masks_obj = sample["boxed_masks_obj"]()
        area_factor = abs(float(np.linalg.det(a[:2, :2])))
        for k, box in enumerate(np.asarray(sample["bbox_obj"])):
            if box[2] <= 0 or box[3] <= 0:
                px_all[k] = 0
                continue
            # the part of the silhouette beyond the scene's image (no mask pixels there)
            beyond = int(px_all[k]) - int(cv2.countNonZero(masks_obj[k]))
            cx0, cy0, cx1, cy1 = _moved_box(a, box, width, height, clip=False)
            canvas_x, canvas_y = self._maps(inverse, cx0, cx1, cy0, cy1)
            odd_x, odd_y = int(box[0]) % 2, int(box[1]) % 2
            source = np.pad(masks_obj[k], ((odd_y, 0), (odd_x, 0)))
            canvas = cv2.remap(source, canvas_x - np.float32(box[0] - odd_x),
                               canvas_y - np.float32(box[1] - odd_y), cv2.INTER_NEAREST,
                               borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            px_all[k] = cv2.countNonZero(canvas) + (
                int(round(beyond * area_factor)) if beyond > 0 else 0)

    def _erase(self, draws, noise_seed, image, instance_map, depth):
        """Noise over a rectangle of the image drawn from `draws` (5 uniforms), nothing of any
        object there in the instance map, no depth: the arrays (copies) and the rectangle
        (x0, y0, x1, y1)."""
        height, width = image.shape[:2]
        area = _uniform(draws[1], *self.erase_area) * width * height
        aspect = _log_uniform(draws[2], *self.erase_aspect)
        ew = min(width, max(1, int(round(math.sqrt(area * aspect)))))
        eh = min(height, max(1, int(round(math.sqrt(area / aspect)))))
        ex = int(draws[3] * (width - ew + 1))
        ey = int(draws[4] * (height - eh + 1))
        noise = np.random.default_rng(noise_seed).integers(
            0, 256, size=(eh, ew, image.shape[2]), dtype=np.uint8)
        image = np.array(image, copy=True)
        image[ey:ey + eh, ex:ex + ew] = noise
        instance_map = np.array(instance_map, copy=True)
        instance_map[ey:ey + eh, ex:ex + ew] = 0
        if depth is not None:
            depth = np.array(depth, copy=True)
            depth[ey:ey + eh, ex:ex + ew] = 0
        return image, instance_map, depth, (ex, ey, ex + ew, ey + eh)

    def __call__(self, sample, rng):
        """Augments one sample. Then exact_labels gives the rest of the labels.

        Args:
            sample: a dict: image (H, W, C) uint8, instance_map (H, W) uint16, depth (H, W)
                uint16 or None, K (3, 3), instance_ids, px_count_all, annotated, ignored,
                bbox_obj and bbox_visib (K, 4) xywh of the candidate instances, and
                boxed_masks_obj: a function that returns their full masks, each within its
                bbox_obj.
            rng: the numpy random generator every draw comes from.

        Returns:
            A new dict with image, instance_map, depth and K transformed, px_count_all
            recomputed, `regions` (where each object's visible pixels can be now) and `affine`
            (the 3x3 A).
        """
        image = sample["image"]
        height, width = image.shape[:2]
        a = self.draw_affine(rng, width, height)
        photometric = rng.random(2)
        erase_draws = rng.random(5)
        noise_seed = int(rng.integers(0, 2 ** 63))
        out = dict(sample)
        px_all = np.asarray(sample["px_count_all"], dtype=np.int64).copy()
        instance_map = sample["instance_map"]
        depth = sample["depth"]

        # geometry: one resampling of each array through the same pixel map
        if not np.allclose(a, np.eye(3), rtol=0, atol=1e-12):
            inverse = np.linalg.inv(a)
            map_x, map_y = self._maps(inverse, 0, width, 0, height)
            border = cv2.BORDER_CONSTANT
            image = cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR, borderMode=border,
                              borderValue=0)
            if image.ndim == 2:
                image = image[:, :, None]
            instance_map = cv2.remap(instance_map, map_x, map_y, cv2.INTER_NEAREST,
                                     borderMode=border, borderValue=0)
            if depth is not None:
                depth = cv2.remap(depth, map_x, map_y, cv2.INTER_NEAREST, borderMode=border,
                                  borderValue=0)
            if len(px_all) > 0:
                self._move_px_count_all(sample, a, inverse, width, height, px_all)
            # where each object's visible pixels can be now
            regions = np.array([_moved_box(a, box, width, height, clip=True)
                                for box in np.asarray(sample["bbox_visib"])],
                               dtype=np.int64).reshape(-1, 4)
            out["K"] = a @ np.asarray(sample["K"], dtype=np.float64)
        else:
            image = image.copy()
            regions = np.array([(x, y, x + w, y + h) for x, y, w, h in
                                np.asarray(sample["bbox_visib"])], dtype=np.int64).reshape(-1, 4)

        # brightness and contrast (the image only: depth and labels are measurements)
        gain = _uniform(photometric[1], 1 - self.contrast, 1 + self.contrast)
        shift = _uniform(photometric[0], -self.brightness, self.brightness) * 255.0
        if gain != 1 or shift != 0:
            mean = float(image.mean())
            image = cv2.addWeighted(image, gain, image, 0, (1 - gain) * mean + shift)
            if image.ndim == 2:
                image = image[:, :, None]

        # random erasure: noise over a rectangle, which hides what lies under it
        if erase_draws[0] < self.erase:
            image, instance_map, depth, out["erased"] = self._erase(
                erase_draws, noise_seed, image, instance_map, depth)

        out["image"] = np.ascontiguousarray(image)
        out["instance_map"] = instance_map
        out["depth"] = depth
        out["px_count_all"] = px_all
        out["regions"] = regions
        out["affine"] = a
        return out
