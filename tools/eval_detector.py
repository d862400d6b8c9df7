"""tools/eval-detector: what a detector learns from a generator config, measured.

Run through tools/eval-detector (which builds what is needed and uses Debian's /usr/bin/python3);
`tools/eval-detector --help` lists the flags. For each --config it makes a training set with
tools/run (the same seed for every config), trains torchvision's Mask R-CNN on it from scratch
(weights=None: nothing is downloaded) with a fixed seed and number of steps, and scores it with
stackgen.metrics on every test set: the paper's MIoU (matches at mask IoU > 0.6; TP / (TP + FP +
FN), ignore regions neither) and COCO mask AP. The test sets are held-out stackgen scenes (the
default config at another seed, made here unless --no-held-out) and any COCO folder given with
--test, e.g. one from tools/make-blender-testset. Prints one line per config and test set, and
with --out writes the same as JSON.

Modes: --mode cpu (default; a small Mask R-CNN, ResNet-18 FPN with light heads, on images scaled
to 320 x 240, 300 steps of 2 images: about 15 minutes for two configs on 2 cores) and --mode gpu
(torchvision's ResNet-50 FPN Mask R-CNN at full size, 3,000 steps of 4, for the paper's numbers
where a GPU is lent).
"""

import argparse
import json
import math
import os
import random
import subprocess
import sys
import tempfile
import time

import toolcli

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

PROGRAM = "eval-detector"
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MODES = {
    # backbone, scale of the images, steps, batch, learning rate, training scenes
    "cpu": dict(backbone="resnet18", scale=0.5, steps=300, batch_size=2, lr=0.02,
                train_scenes=200),
    "gpu": dict(backbone="resnet50", scale=1.0, steps=3000, batch_size=4, lr=0.02,
                train_scenes=2000),
}


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
    parser = toolcli.Parser(PROGRAM, prog="tools/eval-detector", allow_abbrev=False,
                    description="Trains Mask R-CNN on scenes of each config and scores it.",
                    epilog="Exit status: 0 done, 1 error, 2 bad command line.")
    parser.add_argument("--config", action="append", required=True, metavar="FILE",
                        help="a generator config to train on (repeat to compare several)")
    parser.add_argument("--train-dir", action="append", default=[], metavar="DIR",
                        help="instead of making one, the training set of the matching --config "
                             "(a COCO folder; give one per --config, in order)")
    parser.add_argument("--test", action="append", default=[], metavar="DIR",
                        help="a COCO test set (repeatable), e.g. from tools/make-blender-testset")
    parser.add_argument("--no-held-out", action="store_true",
                        help="no held-out stackgen test set (default: --held-out scenes of "
                             "config/default.pbtxt at seed 1000000)")
    parser.add_argument("--held-out", type=toolcli.whole_number(1), default=40, metavar="N",
                        help="held-out stackgen scenes (default 40)")
    parser.add_argument("--mode", choices=sorted(MODES), default="cpu",
                        help="cpu (default: small model and images) or gpu (the paper's model)")
    parser.add_argument("--train-scenes", type=toolcli.whole_number(1), default=None, metavar="N",
                        help="training scenes per config (cpu 200, gpu 2000)")
    parser.add_argument("--steps", type=toolcli.whole_number(1), default=None,
                        help="optimiser steps (cpu 300, gpu 3000)")
    parser.add_argument("--batch-size", type=toolcli.whole_number(1), default=None,
                        help="images per step (cpu 2, gpu 4)")
    parser.add_argument("--scale", type=fraction, default=None,
                        help="image scale for the model (cpu 0.5, gpu 1)")
    parser.add_argument("--seed", type=toolcli.whole_number(0), default=0,
                        help="scene seed of the training sets, model and order seed (default 0)")
    parser.add_argument("--score-threshold", type=fraction, default=0.5,
                        help="the paper's score counts predictions at or above it (default 0.5)")
    parser.add_argument("--device", default=None, help="cpu or cuda (default: the mode's)")
    parser.add_argument("--threads", type=toolcli.whole_number(1), default=os.cpu_count() or 1,
                        help="torch CPU threads (default: the cores)")
    parser.add_argument("--work-dir", default=None,
                        help="where training and held-out sets are made and each trained model "
                             "is kept (default: a temporary folder, removed at the end); a "
                             "second run with the same folder and settings scores the kept "
                             "models on its test sets without training again")
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
    return args


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
    """An image tensor and a torchvision target; ignore regions left out (they are neither
    objects nor background to the loss), all labels class 1."""
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
    tensor = torch.from_numpy(np.ascontiguousarray(image)).permute(2, 0, 1).float() / 255
    return tensor, {"boxes": torch.from_numpy(boxes),
                    "labels": torch.ones(len(masks), dtype=torch.int64),
                    "masks": torch.from_numpy(np.ascontiguousarray(masks))}


def train(args, dataset, name):
    import torch

    device = torch.device(args.device)
    model = build_model(args).to(device)
    model.train()
    parameters = [p for p in model.parameters() if p.requires_grad]
    optimizer = torch.optim.SGD(parameters, lr=args.lr, momentum=0.9, weight_decay=1e-4)
    order = random.Random(args.seed)
    warmup = min(100, args.steps // 4)
    start = time.monotonic()
    indices = []
    for step in range(1, args.steps + 1):
        # a fixed sequence of images and flips, the same for every config
        images, targets = [], []
        for _ in range(args.batch_size):
            if not indices:
                indices = list(range(len(dataset)))
                order.shuffle(indices)
            image, target = to_tensors(dataset, indices.pop(), order.random() < 0.5)
            images.append(image.to(device))
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
          "config, seed %d, work in %s" % (PROGRAM, args.mode, args.backbone, args.scale,
                                           args.steps, args.batch_size, args.train_scenes,
                                           args.seed, work), flush=True)

    # the test sets: held-out stackgen scenes, then the given folders
    tests = []
    if not args.no_held_out:
        held_out = os.path.join(work, "held-out")
        if not os.path.isfile(os.path.join(held_out, "annotations.json")):
            make_dataset(os.path.join(ROOT, "config", "default.pbtxt"), args.held_out, 1000000,
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
            if not os.path.isfile(os.path.join(train_dir, "annotations.json")):
                make_dataset(config, args.train_scenes, args.seed, train_dir,
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
                torch.save(model.state_dict(), kept + ".tmp")
                os.replace(kept + ".tmp", kept)
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
        if args.out:
            temporary = args.out + ".tmp"
            with open(temporary, "w") as file:
                json.dump({"mode": args.mode, "steps": args.steps, "batch_size": args.batch_size,
                           "scale": args.scale, "backbone": args.backbone, "seed": args.seed,
                           "train_scenes": args.train_scenes, "results": results}, file,
                          indent=1)
            os.replace(temporary, args.out)
    if not args.work_dir:
        import shutil
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    try:
        main(sys.argv[1:])
    except KeyboardInterrupt:
        sys.exit(130)
