"""research/eval-detector: what a detector learns from a generator config, measured.

Run through research/eval-detector (which builds what is needed and uses Debian's /usr/bin/python3);
`research/eval-detector --help` lists the flags. For each --config it makes a training set with
tools/run (the same seed for every config), trains torchvision's Mask R-CNN on it from scratch
(weights=None: nothing is downloaded) with a fixed seed and number of steps, and scores it with
stackgen.metrics on every test set: the paper's MIoU (matches at mask IoU > 0.6; TP / (TP + FP +
FN), ignore regions neither) and COCO mask AP. The test sets are held-out stackgen scenes (the
default config at another seed, made here unless --no-held-out) and any COCO folder given with
--test, e.g. one from tools/make-blender-testset. Prints one line per config and test set, and
with --out writes the same as JSON.

Modes: --mode quick (a small segmenter, research/quick_segmenter.py, that learns the task to
saturation in minutes, trained once per --seeds seed, each seed on its own training set: the mean
and spread of foreground IoU and the paper's instance MIoU per config and test set, and where the
wrong pixels lie, with pictures of the worst images), --mode cpu (default; a small Mask R-CNN,
ResNet-18 FPN with light heads, on images scaled to 320 x 240, 300 steps of 2 images: about 15
minutes for two configs on 2 cores) and --mode gpu (torchvision's ResNet-50 FPN Mask R-CNN at full
size, 3,000 steps of 4, for the paper's numbers where a GPU is lent).

The quick mode makes its training and held-out sets with the faster settle rule (1 mm, 1 degree,
0.25 s: the look is what is measured, and stackgen-stats calls those piles the same) and keeps
the parts too hidden to label as ignore regions (annotation.occlusion_rule IGNORE), so that no
visible part pixel is called background; --strict-rest keeps the configs' own settle rule.
"""

import argparse
import json
import math
import os
import random
import re
import statistics
import subprocess
import sys
import tempfile
import time

# the command-line pieces shared with the user's Python tools
sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                                "tools"))
import toolcli  # noqa: E402

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

PROGRAM = "eval-detector"
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MODES = {
    # backbone, scale of the images, steps, batch, learning rate, training scenes
    "cpu": dict(backbone="resnet18", scale=0.5, steps=300, batch_size=2, lr=0.02,
                train_scenes=200),
    "gpu": dict(backbone="resnet50", scale=1.0, steps=3000, batch_size=4, lr=0.02,
                train_scenes=2000),
    "quick": dict(backbone="unet", scale=0.5, steps=4000, batch_size=8, lr=0.004,
                  train_scenes=300),
}
# what the quick mode's sets state over each config (protobuf text, merged field by field)
QUICK_RULES = ("physics { settle_translation_mm: 1 settle_rotation_deg: 1 "
               "settle_window_s: 0.25 }\n")
QUICK_LABELS = "annotation { occlusion_rule: IGNORE }\n"
# config fields holding a path relative to the config's folder
PATH_FIELDS = ("mesh", "collision_mesh", "image_dir", "environment_dir")


def fail(message):
    toolcli.fail(PROGRAM, message)


def fraction(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError("wants a number, got %r" % text) from None
    if not (0 < value <= 1):
        raise argparse.ArgumentTypeError("wants a number in (0, 1], got %r" % text)
    return value


def parse_args(argv):
    parser = toolcli.Parser(PROGRAM, prog="research/eval-detector", allow_abbrev=False,
                    description="Trains Mask R-CNN on scenes of each config and scores it.",
                    epilog="Exit status: 0 done, 1 error, 2 bad command line.")
    parser.add_argument("--config", action="append", required=True, metavar="FILE",
                        help="a generator config to train on (repeat to compare several)")
    parser.add_argument("--train-dir", action="append", default=[], metavar="DIR",
                        help="instead of making one, the training set of the matching --config "
                             "(a COCO folder; give one per --config, in order)")
    parser.add_argument("--test", action="append", default=[], metavar="DIR",
                        help="a COCO test set (repeatable), e.g. from "
                             "research/make-blender-testset")
    parser.add_argument("--no-held-out", action="store_true",
                        help="no held-out stackgen test set (default: --held-out scenes of "
                             "config/default.pbtxt at seed 1000000)")
    parser.add_argument("--held-out", type=toolcli.whole_number(1), default=40, metavar="N",
                        help="held-out stackgen scenes (default 40)")
    parser.add_argument("--mode", choices=sorted(MODES), default="cpu",
                        help="cpu (default: small model and images), gpu (the paper's model) or "
                             "quick (a small segmenter trained to saturation, several seeds)")
    parser.add_argument("--seeds", default=None, metavar="\"S1 S2 ...\"",
                        help="quick mode: the training seeds, each with its own training set "
                             "(scene seed) and model (default \"0 1 2\")")
    parser.add_argument("--strict-rest", action="store_true",
                        help="quick mode: make the sets with the configs' own settle rule "
                             "(default: the faster rule 1 mm, 1 degree, 0.25 s)")
    parser.add_argument("--errors", default=None, metavar="DIR",
                        help="quick mode: pictures of the worst images' errors per config and "
                             "test set (default: WORK_DIR/errors/unetL-S-steps-seed-F, the "
                             "network's levels and steps and the first of --seeds, whose "
                             "pictures they are, -tta added with --tta, so another run keeps "
                             "its own; none without --work-dir)")
    parser.add_argument("--tta", action="store_true",
                        help="quick mode: score each image by the mean of the network's "
                             "predictions over its eight quarter turns and mirror images, each "
                             "turned back (test-time augmentation; the training draws its crops "
                             "in those eight views); kept models are scored again without "
                             "training")
    parser.add_argument("--worst", type=toolcli.whole_number(0), default=4, metavar="N",
                        help="quick mode: images per error picture (default 4)")
    parser.add_argument("--unet-levels", type=toolcli.whole_number(2), default=None, metavar="N",
                        help="quick mode: levels of the U-Net, 2..6, 8 channels doubling per "
                             "level (default 4: 0.12 M weights; 5: 0.49 M)")
    parser.add_argument("--train-scenes", type=toolcli.whole_number(1), default=None, metavar="N",
                        help="training scenes per config (cpu 200, gpu 2000, quick 300)")
    parser.add_argument("--steps", type=toolcli.whole_number(1), default=None,
                        help="optimiser steps (cpu 300, gpu 3000, quick 4000)")
    parser.add_argument("--batch-size", type=toolcli.whole_number(1), default=None,
                        help="images per step (cpu 2, gpu 4, quick 8 crops)")
    parser.add_argument("--scale", type=fraction, default=None,
                        help="image scale for the model (cpu 0.5, gpu 1, quick 0.5)")
    parser.add_argument("--seed", type=toolcli.whole_number(0), default=0,
                        help="scene seed of the training sets, model and order seed (default 0)")
    parser.add_argument("--score-threshold", type=fraction, default=0.5,
                        help="the paper's score counts predictions at or above it (default 0.5)")
    parser.add_argument("--device", default=None, help="cpu or cuda (default: the mode's)")
    parser.add_argument("--threads", type=toolcli.whole_number(1), default=os.cpu_count() or 1,
                        help="torch CPU threads (default: the cores)")
    parser.add_argument("--workers", type=toolcli.whole_number(0), default=0,
                        help="cpu and gpu modes: processes that read the training images ahead "
                             "of the model, the same images in the same order (default 0: the "
                             "training process reads them between steps)")
    parser.add_argument("--work-dir", default=None,
                        help="where training and held-out sets are made and each trained model "
                             "is kept (default: a temporary folder, removed at the end); a "
                             "second run with the same folder and settings scores the kept "
                             "models on its test sets without training again; a kept set made "
                             "from another config text, scene count or seed is refused")
    parser.add_argument("--out", metavar="FILE", help="also write the results as JSON")
    args = parser.parse_args(argv)
    for key, value in MODES[args.mode].items():
        if getattr(args, key, None) is None:
            setattr(args, key, value)
    if args.device is None:
        args.device = "cuda" if args.mode == "gpu" else "cpu"
    if args.train_dir and len(args.train_dir) != len(args.config):
        parser.error("--train-dir: %d given for %d --config" % (len(args.train_dir),
                                                                 len(args.config)))
    for path in args.config:
        if not os.path.isfile(path):
            parser.error("--config %s: no such file" % path)
    for path in args.test + args.train_dir:
        if not os.path.isfile(os.path.join(path, "annotations.json")):
            parser.error("%s: no annotations.json (not a COCO folder)" % path)
    if args.no_held_out and not args.test:
        parser.error("--no-held-out needs a --test set to score on")
    if args.seeds is None:
        args.seeds = [0, 1, 2] if args.mode == "quick" else [args.seed]
    else:
        if args.mode != "quick":
            parser.error("--seeds is for --mode quick (the other modes take --seed)")
        try:
            args.seeds = [toolcli.whole_number(0)(text) for text in args.seeds.split()]
        except argparse.ArgumentTypeError as error:
            parser.error("--seeds: %s" % error)
        if not args.seeds or len(set(args.seeds)) != len(args.seeds):
            parser.error("--seeds wants distinct whole numbers, got %r" % args.seeds)
    if args.mode != "quick" and (args.strict_rest or args.errors or args.unet_levels or args.tta):
        parser.error("--strict-rest, --errors, --unet-levels and --tta are for --mode quick")
    if args.mode == "quick" and args.workers:
        parser.error("--workers is for --mode cpu and gpu")
    if args.unet_levels is None:
        args.unet_levels = 4
    elif args.unet_levels > 6:
        parser.error("--unet-levels wants 2..6, got %d" % args.unet_levels)
    if args.mode == "quick" and args.train_dir and len(args.seeds) > 1:
        parser.error("--train-dir gives one training set per config: with --mode quick give "
                     "one --seeds seed")
    return args


def temporary_name(path, extension=""):
    """Where `path` is written whole before os.replace puts it in place: a name of this
    process's own, so that two calls sharing a work folder never write the same file."""
    return "%s.%d.tmp%s" % (path, os.getpid(), extension)


def save_model(model, path):
    """The model's weights to `path`, whole or not at all."""
    import torch
    temporary = temporary_name(path)
    torch.save(model.state_dict(), temporary)
    os.replace(temporary, path)


def make_dataset(config, count, seed, out, log):
    """tools/run: generator and stackgen-coco on a bus of their own."""
    start = time.monotonic()
    with open(log, "w") as file:
        status = subprocess.call([os.path.join(ROOT, "tools", "run"), "--config", config,
                                  "--count", str(count), "--seed", str(seed), "--out", out],
                                 stdout=file, stderr=subprocess.STDOUT)
    if status != 0:
        with open(log) as file:
            lines = file.read().strip().splitlines()
        fail("tools/run --config %s failed (exit %d): %s" % (config, status,
                                                             lines[-1] if lines else log))
    print("%s: made %d scenes of %s in %.0f s" % (PROGRAM, count, config,
                                                  time.monotonic() - start), flush=True)


STAMP = "made-from.txt"


def work_set_stamp(config, count, seed):
    """What a set of the work folder is made from: the seed, the scene count and the config's
    text (with --work-dir's sets, a changed config file or count must not find the old set)."""
    with open(config) as file:
        return "seed %d, %d scenes, config:\n%s" % (seed, count, file.read())


def check_work_set(config, count, seed, out):
    """Refuses a set `out` of the work folder that a run before made from another config text,
    count or seed, as its stamp says, and one without a stamp: what it was made from is not
    known, and a config name used again would find it."""
    if not os.path.isfile(os.path.join(out, "annotations.json")):
        return
    stamp = os.path.join(out, STAMP)
    if not os.path.isfile(stamp):
        fail("%s: has no %s, so what it was made from is not known (a set from before sets were "
             "stamped): remove it or give another --work-dir" % (out, STAMP))
    with open(stamp) as file:
        if file.read() == work_set_stamp(config, count, seed):
            return
    fail("%s: made from another config, scene count or seed than %s with %d scenes and seed "
         "%d (%s): remove it or give another --work-dir" % (out, config, count, seed, stamp))


def work_set(config, count, seed, out, log):
    """The set `out` of the work folder: `count` scenes of `config` from `seed`, made with
    tools/run and stamped, or the one a run before made there from the same (check_work_set)."""
    check_work_set(config, count, seed, out)
    if os.path.isfile(os.path.join(out, "annotations.json")):
        return
    make_dataset(config, count, seed, out, log)
    with open(os.path.join(out, STAMP), "w") as file:
        file.write(work_set_stamp(config, count, seed))


def build_model(args):
    """gpu: torchvision's Mask R-CNN (ResNet-50 FPN). cpu: the same architecture made small
    enough to train in minutes on two cores: a ResNet-18 body, a 128-channel FPN, half-width
    heads, fewer proposals and sampled RoIs. Both from scratch (weights=None)."""
    import torch
    import torchvision
    from torchvision.models.detection import MaskRCNN, maskrcnn_resnet50_fpn
    from torchvision.models.detection.backbone_utils import BackboneWithFPN
    from torchvision.models.detection.faster_rcnn import FastRCNNPredictor, TwoMLPHead
    from torchvision.models.detection.mask_rcnn import MaskRCNNHeads, MaskRCNNPredictor

    torch.manual_seed(args.seed)
    height, width = round(480 * args.scale), round(640 * args.scale)
    common = dict(num_classes=None if args.backbone != "resnet50" else 2,
                  min_size=height, max_size=width,
                  image_mean=[0.485, 0.456, 0.406], image_std=[0.229, 0.224, 0.225])
    if args.backbone == "resnet50":
        return maskrcnn_resnet50_fpn(weights=None, weights_backbone=None, **common)
    channels = 128
    body = torchvision.models.resnet18(weights=None)
    backbone = BackboneWithFPN(body, {"layer1": "0", "layer2": "1", "layer3": "2", "layer4": "3"},
                               [64, 128, 256, 512], channels)
    return MaskRCNN(
        backbone, **common,
        rpn_pre_nms_top_n_train=600, rpn_post_nms_top_n_train=300,
        rpn_pre_nms_top_n_test=300, rpn_post_nms_top_n_test=150,
        box_head=TwoMLPHead(channels * 7 * 7, 256), box_predictor=FastRCNNPredictor(256, 2),
        box_batch_size_per_image=128, box_detections_per_img=50,
        mask_head=MaskRCNNHeads(channels, (channels, channels), 1),
        mask_predictor=MaskRCNNPredictor(channels, channels, 2))


def to_tensors(dataset, index, flip):
    """An image tensor (uint8, channels first; the model's float is made on its device) and a
    torchvision target; ignore regions left out (they are neither objects nor background to the
    loss), all labels class 1."""
    import numpy as np
    import torch

    image = dataset.image(index)
    masks, labels, iscrowd = dataset.target(index)
    keep = ~iscrowd & (masks.reshape(len(masks), -1).sum(axis=1) > 0)
    masks = masks[keep]
    if flip:
        image = image[:, ::-1]
        masks = masks[:, :, ::-1]
    boxes = np.zeros((len(masks), 4), dtype=np.float32)
    for k, mask in enumerate(masks):
        ys, xs = np.nonzero(mask)
        boxes[k] = [xs.min(), ys.min(), xs.max() + 1, ys.max() + 1]
    tensor = torch.from_numpy(np.ascontiguousarray(image)).permute(2, 0, 1)
    return tensor, {"boxes": torch.from_numpy(boxes),
                    "labels": torch.ones(len(masks), dtype=torch.int64),
                    "masks": torch.from_numpy(np.ascontiguousarray(masks))}


def batch_plan(images, steps, batch_size, seed):
    """The training's images: per step, batch_size (index, flip) pairs, a fixed sequence of
    the seed (every image once per shuffled pass), the same for every config."""
    order = random.Random(seed)
    plan, indices = [], []
    for _ in range(steps):
        batch = []
        for _ in range(batch_size):
            if not indices:
                indices = list(range(images))
                order.shuffle(indices)
            index = indices.pop()
            batch.append((index, order.random() < 0.5))
        plan.append(batch)
    return plan


class PlannedBatches:
    """The batches of a plan as a torch Dataset: item k is step k + 1's list of (image, target)."""

    def __init__(self, dataset, plan):
        self.dataset, self.plan = dataset, plan

    def __len__(self):
        return len(self.plan)

    def __getitem__(self, step):
        return [to_tensors(self.dataset, index, flip) for index, flip in self.plan[step]]

    @staticmethod
    def collate(items):
        return items[0]


def training_batches(args, dataset):
    """Step by step, the (image uint8 CHW, target) pairs of batch_plan: read here between steps
    (--workers 0) or ahead by --workers processes, each a prefetch of 4 batches."""
    import torch

    batches = PlannedBatches(dataset, batch_plan(len(dataset), args.steps, args.batch_size,
                                                 args.seed))
    if args.workers == 0:
        return (batches[k] for k in range(len(batches)))
    return iter(torch.utils.data.DataLoader(batches, batch_size=1, shuffle=False,
                                            num_workers=args.workers, prefetch_factor=4,
                                            collate_fn=PlannedBatches.collate))


def train(args, dataset, name):
    import torch

    device = torch.device(args.device)
    model = build_model(args).to(device)
    model.train()
    parameters = [p for p in model.parameters() if p.requires_grad]
    optimizer = torch.optim.SGD(parameters, lr=args.lr, momentum=0.9, weight_decay=1e-4)
    warmup = min(100, args.steps // 4)
    start = time.monotonic()
    batches = training_batches(args, dataset)
    for step in range(1, args.steps + 1):
        images, targets = [], []
        for image, target in next(batches):
            images.append(image.to(device).float() / 255)
            targets.append({k: v.to(device) for k, v in target.items()})
        # linear warm-up, then cosine decay
        if step <= warmup:
            lr = args.lr * step / warmup
        else:
            lr = 0.5 * args.lr * (1 + math.cos(math.pi * (step - warmup) / (args.steps - warmup)))
        for group in optimizer.param_groups:
            group["lr"] = lr
        losses = model(images, targets)
        loss = sum(losses.values())
        if not math.isfinite(loss.item()):
            fail("%s: the loss is %s at step %d" % (name, loss.item(), step))
        optimizer.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(parameters, 10.0)
        optimizer.step()
        if step % 25 == 0 or step == args.steps:
            elapsed = time.monotonic() - start
            print("%s: %s: step %d/%d, loss %.3f, %.1f s per step" % (
                PROGRAM, name, step, args.steps, loss.item(), elapsed / step), flush=True)
    return model


def evaluate(args, model, dataset):
    import stackgen.torch as sgt

    return sgt.evaluate(model, dataset, device=args.device, score_threshold=args.score_threshold)


def merged_config(config, overlay, out):
    """Writes to `out` the config with `overlay` (protobuf text) merged into it as protobuf
    merges messages (protoc encodes both; the two encodings one after the other are the merge;
    protoc decodes it), its paths made absolute; returns the text."""
    types = os.path.join(ROOT, "types")

    def protoc(action, data):
        result = subprocess.run(["protoc", "-I", types,
                                 "%s=stackgen.config.GeneratorConfig" % action,
                                 "stackgen_config.proto"], input=data, capture_output=True)
        if result.returncode != 0:
            lines = result.stderr.decode(errors="replace").strip().splitlines()
            fail("%s: %s" % (config, lines[-1] if lines else "protoc failed"))
        return result.stdout

    with open(config, "rb") as file:
        merged = protoc("--encode", file.read()) + protoc("--encode", overlay.encode())
    text = protoc("--decode", merged).decode()
    folder = os.path.dirname(os.path.abspath(config))

    def absolute(match):
        path = match.group(3)
        if path and not os.path.isabs(path):
            path = os.path.normpath(os.path.join(folder, path))
        return '%s%s: "%s"' % (match.group(1), match.group(2), path)

    text = re.sub(r'^(\s*)(%s): "([^"]*)"$' % "|".join(PATH_FIELDS), absolute, text, flags=re.M)
    temporary = temporary_name(out)
    with open(temporary, "w") as file:
        file.write(text)
    os.replace(temporary, out)
    return text


def bin_size(text):
    """(inner length, inner width, inner height, wall) in mm of a config's box bin (the
    defaults where the text leaves a field out)."""
    block = re.search(r"^bin \{\n(.*?)^\}", text, re.M | re.S)
    sizes = []
    for name, default in (("inner_length_mm", 200), ("inner_width_mm", 150),
                          ("inner_height_mm", 100), ("wall_thickness_mm", 8)):
        found = block and re.search(r"^\s*%s: (\S+)$" % name, block.group(1), re.M)
        sizes.append(float(found.group(1)) if found else float(default))
    return tuple(sizes)


def spread(values):
    """(mean, spread = largest - smallest, sample standard deviation) of per-seed figures."""
    return (statistics.fmean(values), max(values) - min(values),
            statistics.stdev(values) if len(values) > 1 else 0.0)


def error_line(pixels):
    """Where the wrong pixels lie (ForegroundScores' counts, pooled): one line."""
    missed, false = pixels["false_negative"], pixels["false_positive"]
    total_missed, total_false = sum(missed.values()), sum(false.values())
    parts = ["missed %d px: %.0f %% along outlines, %.0f %% inside parts" % (
        total_missed, 100 * missed["edges"] / max(1, total_missed),
        100 * missed["inside parts"] / max(1, total_missed))]
    where = []
    for cause, count in false.items():
        if count == 0 and cause != "edges":
            continue
        rate = pixels["fp_rate"].get(cause)
        where.append("%.0f %% %s%s" % (100 * count / max(1, total_false),
                                        "along outlines" if cause == "edges" else "on " + cause,
                                        "" if rate is None or rate != rate else
                                        " (%.2f %% of it)" % (100 * rate)))
    parts.append("false %d px: %s" % (total_false, ", ".join(where)))
    return "; ".join(parts)


def pooled_pixels(results):
    """The ForegroundScores results of several seeds added up."""
    pooled = {"false_negative": {}, "false_positive": {}, "fp_rate": {}}
    region_px = {}
    for result in results:
        for key in ("false_negative", "false_positive"):
            for cause, count in result[key].items():
                pooled[key][cause] = pooled[key].get(cause, 0) + count
        for cause, rate in result["fp_rate"].items():
            if rate == rate and rate > 0:
                region_px[cause] = region_px.get(cause, 0) + \
                    result["false_positive"][cause] / rate
    for cause in pooled["false_positive"]:
        if cause in region_px:
            pooled["fp_rate"][cause] = pooled["false_positive"][cause] / region_px[cause]
    return pooled


def write_pictures(path, pictures):
    """The worst images' error pictures side by side, two to a row, as one JPEG."""
    import cv2
    import numpy as np

    tiles = [picture for _, _, picture in pictures]
    if len(tiles) % 2:
        tiles.append(np.zeros_like(tiles[0]))
    rows = [np.hstack(tiles[k:k + 2]) for k in range(0, len(tiles), 2)]
    temporary = temporary_name(path, ".jpg")
    cv2.imwrite(temporary, np.vstack(rows), [cv2.IMWRITE_JPEG_QUALITY, 85])
    os.replace(temporary, path)


def quick_model(args, config, train_dir, seed):
    """The quick mode's segmenter of one config and seed: trained now, or the one kept in the
    work folder from a run with the same settings."""
    import torch
    import quick_segmenter
    from stackgen.coco import CocoDataset

    name = "%s, seed %d" % (os.path.basename(config), seed)
    # the name holds the depth, except for the default four levels
    kept = None if args.train_dir else os.path.join(
        train_dir, "quick-unet%s-%d-steps-%d-of-%d-x%.3f-lr%g-seed-%d.pt" % (
            "" if args.unet_levels == 4 else args.unet_levels, args.train_scenes, args.steps,
            args.batch_size, args.scale, args.lr, seed))
    model = quick_segmenter.build_model(seed, args.unet_levels)
    if kept and os.path.isfile(kept):
        model.load_state_dict(torch.load(kept))
        model.eval()
        print("%s: %s: the model trained before, %s" % (PROGRAM, name, kept), flush=True)
        return model, 0.0
    start = time.monotonic()

    def log(text):
        print("%s: %s: %s" % (PROGRAM, name, text), flush=True)

    images, targets = quick_segmenter.load_training_set(CocoDataset(train_dir), args.scale, log)
    try:
        quick_segmenter.train(model, images, targets, args.steps, args.batch_size,
                              quick_segmenter.CROP_PX, args.lr, seed, log)
    except RuntimeError as error:
        fail("%s: %s" % (name, error))
    if kept:
        save_model(model, kept)
    return model, time.monotonic() - start


def scene_kinds(folder, dataset):
    """Each image's kind of scene from the README.txt of an independent set
    (research/make-blender-testset writes "images/000003.png: white tote (0.85, ...), ..."): the
    words before the first "(" or ",", in the dataset's order; None when the folder has no such
    line for every image."""
    path = os.path.join(folder, "README.txt")
    if not os.path.isfile(path):
        return None
    kinds = {}
    with open(path) as file:
        for line in file:
            match = re.match(r"(images/[^:\s]+): ([^(,]+)", line)
            if match:
                kinds[os.path.normpath(os.path.join(folder, match.group(1)))] = \
                    match.group(2).strip()
    names = [os.path.normpath(dataset.image_path(i)) for i in range(len(dataset))]
    if not names or any(name not in kinds for name in names):
        return None
    return [kinds[name] for name in names]


def by_kind(per_image, kinds):
    """Foreground IoU per kind of scene: per_image holds each seed's list of per-image IoUs
    (the dataset's order), kinds each image's kind. [(kind, mean over its images and the seeds,
    images)], the lowest first."""
    groups = {}
    for seed_ious in per_image:
        for iou, kind in zip(seed_ious, kinds):
            groups.setdefault(kind, []).append(iou)
    return sorted(((kind, sum(v) / len(v), kinds.count(kind)) for kind, v in groups.items()),
                  key=lambda entry: (entry[1], entry[0]))


def run_quick(args, work):
    """The quick mode: per config and seed a training set and a segmenter, scored on every test
    set; per config and test set the mean and spread over the seeds, and where the errors lie."""
    import quick_segmenter
    from stackgen.coco import CocoDataset

    overlay = QUICK_LABELS + ("" if args.strict_rest else QUICK_RULES)
    # every set of the work folder checked before anything is made or trained
    merged_configs = []
    for k, config in enumerate(args.config):
        stem = os.path.splitext(os.path.basename(config))[0]
        merged_configs.append(os.path.join(work, "config-%d-%s.pbtxt" % (k, stem)))
        merged_config(config, overlay, merged_configs[-1])
        for seed in [] if args.train_dir else args.seeds:
            check_work_set(merged_configs[-1], args.train_scenes, seed,
                           os.path.join(work, "train-%d-%s-seed-%d" % (k, stem, seed)))
    tests = []
    if not args.no_held_out:
        held_out = os.path.join(work, "held-out")
        text = merged_config(os.path.join(ROOT, "config", "default.pbtxt"), overlay,
                             os.path.join(work, "held-out.pbtxt"))
        work_set(os.path.join(work, "held-out.pbtxt"), args.held_out, 1000000, held_out,
                 os.path.join(work, "held-out.log"))
        tests.append(("held-out stackgen", CocoDataset(held_out), bin_size(text)))
    kinds = {}  # test name: each image's kind of scene, from an independent set's README.txt
    for path in args.test:
        name, dataset = os.path.basename(os.path.normpath(path)), CocoDataset(path)
        tests.append((name, dataset, None))
        kinds[name] = scene_kinds(path, dataset)
    errors = args.errors or (os.path.join(args.work_dir, "errors", "unet%d-%d-steps-seed-%d%s" % (
        args.unet_levels, args.steps, args.seeds[0], "-tta" if args.tta else "")) if
        args.work_dir else None)
    if errors:
        os.makedirs(errors, exist_ok=True)

    results, summaries = [], []
    for k, config in enumerate(args.config):
        stem = os.path.splitext(os.path.basename(config))[0]
        merged = merged_configs[k]
        for seed in args.seeds:
            if args.train_dir:
                train_dir = args.train_dir[k]
            else:
                train_dir = os.path.join(work, "train-%d-%s-seed-%d" % (k, stem, seed))
                work_set(merged, args.train_scenes, seed, train_dir,
                         os.path.join(work, "train-%d-seed-%d.log" % (k, seed)))
            model, trained_s = quick_model(args, config, train_dir, seed)
            for test_name, dataset, size in tests:
                worst = args.worst if errors and seed == args.seeds[0] else 0
                pixels, detections, pictures = quick_segmenter.score(model, dataset, args.scale,
                                                                     size, worst, args.tta)
                if pictures:
                    write_pictures(os.path.join(errors, "%s-%s.jpg" % (
                        stem, re.sub(r"[^A-Za-z0-9_.-]+", "-", test_name))), pictures)
                result = dict(config=config, test=test_name, seed=seed,
                              train_seconds=round(trained_s, 1), foreground_iou=pixels["iou"],
                              per_image_iou=pixels["per_image_iou"],
                              pixels={key: pixels[key] for key in (
                                  "false_negative", "false_positive", "fp_rate")},
                              **detections)
                results.append(result)
                print("%s: %s, seed %d, on %s: foreground IoU %.3f, MIoU %.3f (TP %d, FP %d, "
                      "FN %d), mask AP50 %.3f (%d images)" % (
                          PROGRAM, os.path.basename(config), seed, test_name, pixels["iou"],
                          detections["miou"], detections["tp"], detections["fp"],
                          detections["fn"], detections["ap50"], detections["images"]),
                      flush=True)
        # mean and spread over the seeds, per test set
        for test_name, _, _ in tests:
            mine = [r for r in results if r["config"] == config and r["test"] == test_name]
            iou, miou = spread([r["foreground_iou"] for r in mine]), \
                spread([r["miou"] for r in mine])
            pooled = pooled_pixels([r["pixels"] for r in mine])
            summaries.append(dict(config=config, test=test_name, seeds=args.seeds,
                                  foreground_iou=dict(zip(("mean", "spread", "sd"), iou)),
                                  miou=dict(zip(("mean", "spread", "sd"), miou)),
                                  pixels=pooled))
            if kinds.get(test_name):
                summaries[-1]["by_kind"] = [
                    dict(kind=kind, foreground_iou=mean, images=images) for kind, mean, images in
                    by_kind([r["per_image_iou"] for r in mine], kinds[test_name])]
        write_results(args, results, summaries)
    print("%s: quick mode, seeds %s: mean over the seeds (spread = largest - smallest)" % (
        PROGRAM, " ".join(map(str, args.seeds))), flush=True)
    for summary in summaries:
        iou, miou = summary["foreground_iou"], summary["miou"]
        print("%s: %s on %s: foreground IoU %.3f (spread %.3f, sd %.3f), MIoU %.3f (spread "
              "%.3f)\n    %s" % (PROGRAM, os.path.basename(summary["config"]), summary["test"],
                                 iou["mean"], iou["spread"], iou["sd"], miou["mean"],
                                 miou["spread"], error_line(summary["pixels"])), flush=True)
        if "by_kind" in summary:
            print("    by the kind of scene its README.txt names (foreground IoU of its images, "
                  "the seeds pooled; lowest first): %s" % ", ".join(
                      "%s %.3f (%d)" % (k["kind"], k["foreground_iou"], k["images"])
                      for k in summary["by_kind"]), flush=True)
    if errors:
        print("%s: pictures of the worst images' errors (seed %d; green found, red false, blue "
              "missed, grey ignored): %s" % (PROGRAM, args.seeds[0], errors), flush=True)


def write_results(args, results, summaries=None):
    """The results so far as JSON (--out), written whole or not at all."""
    if not args.out:
        return
    written = {"mode": args.mode, "steps": args.steps, "batch_size": args.batch_size,
               "scale": args.scale, "backbone": args.backbone, "seed": args.seed,
               "train_scenes": args.train_scenes, "results": results}
    if summaries is not None:
        written.update(seeds=args.seeds, strict_rest=args.strict_rest,
                       unet_levels=args.unet_levels, tta=args.tta, summaries=summaries)
    temporary = temporary_name(args.out)
    with open(temporary, "w") as file:
        json.dump(written, file, indent=1)
    os.replace(temporary, args.out)


def main(argv):
    args = parse_args(argv)
    import torch

    sys.path.insert(0, os.path.join(ROOT, "build", "python"))
    from stackgen.coco import CocoDataset

    if args.device.startswith("cuda") and not torch.cuda.is_available():
        fail("--device %s: torch has no CUDA device here (torch %s)" % (args.device,
                                                                       torch.__version__))
    torch.set_num_threads(args.threads)
    work = args.work_dir or tempfile.mkdtemp(prefix="stackgen-eval-detector.")
    os.makedirs(work, exist_ok=True)
    print("%s: %s mode: %s backbone, images x %.2f, %d steps of %d, %d training scenes per "
          "config, seed%s %s, work in %s" % (
              PROGRAM, args.mode, args.backbone, args.scale, args.steps, args.batch_size,
              args.train_scenes, "s" if len(args.seeds) > 1 else "",
              " ".join(map(str, args.seeds)), work), flush=True)
    if args.mode == "quick":
        print("%s: the sets are made with %sthe hidden parts as ignore regions (%s)" % (
            PROGRAM, "" if args.strict_rest else "the faster settle rule (%s) and " %
            QUICK_RULES.strip(), QUICK_LABELS.strip()), flush=True)
        if args.tta:
            print("%s: each test image scored by the mean over its eight quarter turns and "
                  "mirror images (--tta)" % PROGRAM, flush=True)
        run_quick(args, work)
        if not args.work_dir:
            import shutil
            shutil.rmtree(work, ignore_errors=True)
        return

    # the test sets: held-out stackgen scenes, then the given folders
    for k, config in enumerate([] if args.train_dir else args.config):
        check_work_set(config, args.train_scenes, args.seed, os.path.join(
            work, "train-%d-%s" % (k, os.path.splitext(os.path.basename(config))[0])))
    tests = []
    if not args.no_held_out:
        held_out = os.path.join(work, "held-out")
        work_set(os.path.join(ROOT, "config", "default.pbtxt"), args.held_out, 1000000,
                 held_out, os.path.join(work, "held-out.log"))
        tests.append(("held-out stackgen (default config)", CocoDataset(held_out)))
    for path in args.test:
        tests.append((path, CocoDataset(path)))

    results = []
    for k, config in enumerate(args.config):
        name = os.path.basename(config)
        if args.train_dir:
            train_dir = args.train_dir[k]
        else:
            train_dir = os.path.join(work, "train-%d-%s" % (k, os.path.splitext(name)[0]))
            work_set(config, args.train_scenes, args.seed, train_dir,
                     os.path.join(work, "train-%d.log" % k))
        # a model trained before on a training set of this work folder with the same settings is
        # scored again (a --train-dir folder is the user's: nothing is written there)
        kept = None if args.train_dir else os.path.join(
            train_dir, "model-%s-%s-%d-steps-%d-of-%d-x%.3f-lr%g-seed-%d.pt" % (
                args.mode, args.backbone, args.train_scenes, args.steps, args.batch_size,
                args.scale, args.lr, args.seed))
        start = time.monotonic()
        if kept and os.path.isfile(kept):
            model = build_model(args).to(torch.device(args.device))
            model.load_state_dict(torch.load(kept, map_location=args.device))
            print("%s: %s: the model trained before, %s" % (PROGRAM, name, kept), flush=True)
        else:
            model = train(args, CocoDataset(train_dir), name)
            if kept:
                save_model(model, kept)
        trained_s = time.monotonic() - start
        for test_name, test in tests:
            result = evaluate(args, model, test)
            result.update(config=config, test=test_name, train_seconds=round(trained_s, 1))
            results.append(result)
            print("%s: %s on %s: MIoU %.3f (TP %d, FP %d, FN %d), mask AP %.3f, AP50 %.3f "
                  "(%d images)" % (PROGRAM, name, test_name, result["miou"], result["tp"],
                                   result["fp"], result["fn"], result["ap"], result["ap50"],
                                   result["images"]), flush=True)
        # the results so far, after each config: a run cut short keeps what it measured
        write_results(args, results)
    if not args.work_dir:
        import shutil
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    try:
        main(sys.argv[1:])
    except KeyboardInterrupt:
        sys.exit(130)
