"""How the pictures of COCO sets differ: grey level, contrast and colour of the parts and of the
whole images, so that a look can be compared with a test set before anything is trained on it.

For each image it measures, with OpenCV's grey level (0..255) and HSV saturation (0..255):
  - over the labelled part pixels (annotations with iscrowd 0; ignore regions are left out): the
    mean grey level, the mean saturation and the share of pixels clipped white (grey >= 250);
  - over the whole image: the mean grey level, its standard deviation (a flat picture has a small
    one) and the mean saturation.
It prints, for each set, the median over its images and the 10th and 90th percentiles (numpy's
linear interpolation); an image without a labelled part pixel counts in the whole-image figures
only. --json FILE writes the same figures, per set, to FILE (through a temporary name).

    research/image-stats DIR [DIR ...] [--limit N] [--json FILE]

DIR is a COCO folder (annotations.json, images in DIR/images or DIR): one stackgen-coco wrote
(e.g. `tools/run --count 40 --out DIR`), or a set of research/make-independent-sets. Bad input is
refused in one line naming the folder or flag, exit 2, before anything is read or written.
"""

import argparse
import json
import os
import sys

import cv2
import numpy as np

from stackgen.coco import CocoDataset

# the figures, in the order printed: (key, heading, over which pixels)
FIGURES = [
    ("part_grey", "part grey", "part"),
    ("part_saturation", "part saturation", "part"),
    ("part_clipped", "part clipped", "part"),
    ("grey", "grey", "image"),
    ("grey_sd", "grey sd", "image"),
    ("saturation", "saturation", "image"),
]
CLIPPED_GREY = 250


def image_figures(rgb, masks, iscrowd):
    """The figures of one image.

    Args:
        rgb: (H, W, 3) uint8 RGB.
        masks: (K, H, W) 0/1 instance masks.
        iscrowd: (K) bool, true for ignore regions.

    Returns:
        {key: value} with every key of FIGURES; the part figures are NaN when no labelled part
        pixel is in the image.
    """
    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float64)
    saturation = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)[..., 1].astype(np.float64)
    part = np.zeros(grey.shape, bool)
    for mask, crowd in zip(masks, iscrowd):
        if not crowd:
            part |= mask.astype(bool)
    figures = {"grey": grey.mean(), "grey_sd": grey.std(), "saturation": saturation.mean()}
    if part.any():
        figures.update(part_grey=grey[part].mean(), part_saturation=saturation[part].mean(),
                       part_clipped=(grey[part] >= CLIPPED_GREY).mean())
    else:
        figures.update(part_grey=np.nan, part_saturation=np.nan, part_clipped=np.nan)
    return figures


def set_figures(dataset, limit=None):
    """The median, 10th and 90th percentile of each figure over a set's images.

    Args:
        dataset: a CocoDataset.
        limit: read only the first `limit` images (file-name order); None: all.

    Returns:
        {"images": n, key: {"median": m, "p10": a, "p90": b}, ...}; a part figure of a set with
        no labelled part pixel at all is None.
    """
    count = len(dataset) if limit is None else min(limit, len(dataset))
    rows = []
    for index in range(count):
        masks, _, iscrowd = dataset.target(index)
        rows.append(image_figures(dataset.image(index), masks, iscrowd))
    out = {"images": count}
    for key, _, _ in FIGURES:
        values = np.array([row[key] for row in rows], np.float64)
        values = values[~np.isnan(values)]
        out[key] = None if values.size == 0 else {
            "median": float(np.median(values)), "p10": float(np.percentile(values, 10)),
            "p90": float(np.percentile(values, 90))}
    return out


def format_figure(key, figure):
    if figure is None:
        return "-"
    scale, digits = (100, 1) if key == "part_clipped" else (1, 0)
    unit = " %" if key == "part_clipped" else ""
    return "%.*f%s (%.*f-%.*f)" % (digits, scale * figure["median"], unit, digits,
                                   scale * figure["p10"], digits, scale * figure["p90"])


def fail(message):
    """Refuses bad input in one line, exit 2."""
    print("research/image-stats: error: %s" % message, file=sys.stderr)
    sys.exit(2)


def main(argv=None):
    parser = argparse.ArgumentParser(
        prog="research/image-stats",
        description="Grey level, contrast and colour of the parts and of the whole images of COCO "
                    "sets: the median over each set's images (10th-90th percentile).")
    parser.add_argument("folders", nargs="+", metavar="DIR", help="COCO folders")
    parser.add_argument("--limit", type=int, default=None, metavar="N",
                        help="read only each set's first N images (file-name order)")
    parser.add_argument("--json", default=None, metavar="FILE",
                        help="also write the figures to FILE (JSON)")
    args = parser.parse_args(argv)
    if args.limit is not None and args.limit < 1:
        fail("--limit %d: want a whole number >= 1" % args.limit)
    # check everything before reading an image or writing a byte
    datasets = []
    for folder in args.folders:
        if not os.path.isfile(os.path.join(folder, "annotations.json")):
            fail("%s: no annotations.json (not a COCO folder)" % folder)
        try:
            dataset = CocoDataset(folder)
        except ValueError as error:
            fail(str(error))
        if len(dataset) == 0:
            fail("%s: annotations.json lists no image" % folder)
        datasets.append(dataset)
    if args.json is not None:
        parent = os.path.dirname(os.path.abspath(args.json))
        if not os.path.isdir(parent):
            fail("--json %s: no folder %s" % (args.json, parent))

    results = {}
    width = max(len(folder) for folder in args.folders)
    print("%-*s  images  %s" % (width, "set", "  ".join(
        "%-21s" % heading for _, heading, _ in FIGURES)))
    for folder, dataset in zip(args.folders, datasets):
        try:
            figures = set_figures(dataset, args.limit)
        except ValueError as error:
            print("research/image-stats: error: %s" % error, file=sys.stderr)
            return 1
        results[folder] = figures
        print("%-*s  %6d  %s" % (width, folder, figures["images"], "  ".join(
            "%-21s" % format_figure(key, figures[key]) for key, _, _ in FIGURES)), flush=True)
    print("(median over the images, 10th-90th percentile in brackets; part figures over labelled "
          "part pixels, the others over whole images; grey and saturation 0..255)")
    if args.json is not None:
        temporary = args.json + ".tmp"
        with open(temporary, "w") as file:
            json.dump(results, file, indent=1, sort_keys=True)
        os.replace(temporary, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
