"""tools/coco-to-yolo: a COCO dataset of stackgen-coco (or any COCO folder) as an Ultralytics
YOLO segmentation dataset.

Run through tools/coco-to-yolo (which builds the Python package and uses Debian's
/usr/bin/python3). Each split is one COCO folder, given as NAME=DIR (e.g. the folders of
`tools/run --split train=0.9,val=0.1`); one folder alone is the split "train", also named as
"val" in data.yaml (Ultralytics wants one). Writes into --out, which must be absent or empty:

    images/NAME/FILE        the image (a hard link where the file system allows, else a copy)
    labels/NAME/FILE.txt    one line per object: class x1 y1 x2 y2 ... (the outline of its
                            visible mask, normalised to 0..1 by the image's width and height)
    data.yaml               path, train, val, names (class index: category id order)

The rule: iscrowd 0 annotations become labels; ignore regions (iscrowd 1) are left out, and YOLO
has no ignore, so the trainer takes them as background (use the occlusion rule DROP where that
matters). An object whose visible mask falls into several pieces (a part seen on both sides of
another) or has holes (the connector's bolt holes) becomes one outline: pieces and holes joined
by zero-width cuts, as Ultralytics' own COCO converter joins pieces. Filled back (cv2.fillPoly,
as Ultralytics does) an outline gives the mask again, holes open, plus the pixels along the cuts
between pieces (a small part in three pieces: IoU 0.84; on the fixture scenes 0.99 on average).
Classes are numbered 0, 1, ... in the order of their COCO category ids.
Everything is written under a temporary name and renamed when whole.
"""

import json
import os
import shutil
import sys

import toolcli

PROGRAM = "coco-to-yolo"


def fail(message):
    toolcli.fail(PROGRAM, message)


def outline(mask):
    """One closed polygon [(x, y), ...] in pixel coordinates of the mask: its outer contours and
    its holes' (through the centres of the boundary pixels, straight runs as their two ends),
    joined into one by zero-width cuts between nearest points."""
    import cv2
    import numpy as np

    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_CCOMP,
                                   cv2.CHAIN_APPROX_SIMPLE)
    pieces = [c.reshape(-1, 2).astype(np.float64) for c in contours if len(c) > 0]
    if not pieces:
        return None
    # the largest first; each next piece joined at its point nearest to what is joined so far
    pieces.sort(key=lambda p: -cv2.contourArea(p.astype(np.float32)))
    polygon = pieces[0]
    for piece in pieces[1:]:
        distances = ((polygon[:, None, :] - piece[None, :, :]) ** 2).sum(axis=2)
        i, j = np.unravel_index(np.argmin(distances), distances.shape)
        # ... -> polygon[i] -> piece[j] around piece back to piece[j] -> polygon[i] -> ...
        around = np.concatenate([piece[j:], piece[:j + 1]])
        polygon = np.concatenate([polygon[:i + 1], around, polygon[i:]])
    return polygon


def convert_split(name, folder, out, classes):
    from stackgen.coco import CocoDataset

    dataset = CocoDataset(folder)
    os.makedirs(os.path.join(out, "images", name))
    os.makedirs(os.path.join(out, "labels", name))
    objects = ignored = 0
    for index in range(len(dataset)):
        image = dataset.images[index]
        width, height = image["width"], image["height"]
        source = dataset.image_path(index)
        if not os.path.isfile(source):
            fail("%s: image %s is missing" % (folder, source))
        base = os.path.basename(image["file_name"])
        target = os.path.join(out, "images", name, base)
        if os.path.exists(target):
            fail("%s: two images named %s" % (folder, base))
        try:
            os.link(source, target)
        except OSError:
            shutil.copyfile(source, target)
        masks, labels, iscrowd = dataset.target(index)
        lines = []
        for mask, label, crowd in zip(masks, labels, iscrowd):
            if crowd:
                ignored += 1
                continue
            if int(label) not in classes:
                fail("%s: image %s has category id %d, not among the categories" % (
                    folder, image["file_name"], label))
            polygon = outline(mask)
            if polygon is None:
                continue
            points = " ".join("%.6f %.6f" % (x / width, y / height) for x, y in polygon)
            lines.append("%d %s" % (classes[int(label)], points))
            objects += 1
        stem = os.path.splitext(base)[0]
        with open(os.path.join(out, "labels", name, stem + ".txt"), "w") as file:
            file.write("".join(line + "\n" for line in lines))
    return len(dataset), objects, ignored


def main(argv):
    parser = toolcli.Parser(PROGRAM, prog="tools/coco-to-yolo",
                            description="A COCO dataset as an Ultralytics YOLO segmentation "
                                        "dataset (images/, labels/, data.yaml).")
    parser.add_argument("splits", nargs="+", metavar="[NAME=]COCO_DIR",
                        help="a COCO folder per split (NAME a lower-case word); one folder "
                             "alone is the split train")
    parser.add_argument("--out", required=True, metavar="DIR",
                        help="the YOLO dataset folder (absent or empty)")
    args = parser.parse_args(argv)

    splits = []
    for text in args.splits:
        name, sep, folder = text.partition("=")
        if not sep:
            if len(args.splits) > 1:
                parser.error("%s: name each split (NAME=DIR) when there are several" % text)
            name, folder = "train", text
        if not name.isidentifier() or name != name.lower() or name in dict(splits):
            parser.error("%s: a split needs a lower-case name, once" % text)
        if not os.path.isfile(os.path.join(folder, "annotations.json")):
            parser.error("%s: no annotations.json (not a COCO folder)" % folder)
        splits.append((name, folder))
    if os.path.exists(args.out) and (not os.path.isdir(args.out) or os.listdir(args.out)):
        parser.error("--out %s is not an empty folder" % args.out)

    sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(
        __file__))), "build", "python"))
    # the classes: every split's categories, the same names for the same ids
    categories = {}
    for _, folder in splits:
        path = os.path.join(folder, "annotations.json")
        try:
            with open(path) as file:
                found = {c["id"]: c["name"] for c in json.load(file)["categories"]}
        except (OSError, ValueError, KeyError, TypeError) as error:
            fail("%s: no categories: %s" % (path, error))
        for category_id, category_name in found.items():
            if categories.setdefault(category_id, category_name) != category_name:
                fail("%s: category %d is %r here, %r in another split" % (
                    path, category_id, category_name, categories[category_id]))
    classes = {category_id: k for k, category_id in enumerate(sorted(categories))}

    out = os.path.abspath(args.out)
    temporary = out + ".tmp-%d" % os.getpid()
    shutil.rmtree(temporary, ignore_errors=True)
    try:
        for name, folder in splits:
            images, objects, ignored = convert_split(name, folder, temporary, classes)
            print("%s: %s: %d images, %d objects, %d ignore regions left out (%s)" % (
                PROGRAM, name, images, objects, ignored, folder), flush=True)
        names = [name for name, _ in splits]
        val = "val" if "val" in names else names[-1]
        with open(os.path.join(temporary, "data.yaml"), "w") as file:
            file.write("# made by stackgen's tools/coco-to-yolo from %s\n" % ", ".join(
                folder for _, folder in splits))
            file.write("path: %s\n" % json.dumps(out))
            file.write("train: images/%s\n" % names[0])
            file.write("val: images/%s\n" % val)
            for name in names:
                if name not in (names[0], val):
                    file.write("%s: images/%s\n" % (name, name))
            file.write("names:\n")
            for category_id, k in sorted(classes.items(), key=lambda item: item[1]):
                file.write("  %d: %s\n" % (k, json.dumps(categories[category_id])))
        if os.path.isdir(out):
            os.rmdir(out)
        os.rename(temporary, out)
    except BaseException:
        shutil.rmtree(temporary, ignore_errors=True)
        raise
    print("%s: wrote %s (data.yaml, images/, labels/); classes: %s" % (
        PROGRAM, out, ", ".join("%d %s" % (k, categories[category_id]) for category_id, k in
                                sorted(classes.items(), key=lambda item: item[1]))))
    if val == names[0]:
        print("%s: warning: one split only: data.yaml's val is the training set itself, so a "
              "validation score says nothing about new scenes; make a held-out split with "
              "tools/run --split train=0.9,val=0.1 and pass both folders" % PROGRAM,
              file=sys.stderr)


if __name__ == "__main__":
    try:
        main(sys.argv[1:])
    except KeyboardInterrupt:
        sys.exit(130)
