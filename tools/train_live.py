"""tools/train-live: trains torchvision's Mask R-CNN live on scenes from stackgen generators.

Run through tools/train-live (which builds what is needed and uses Debian's /usr/bin/python3);
`tools/train-live --help` lists the flags. It starts generators on a bus of its own (or attaches
to running ones), reads their scenes through stackgen.torch.StreamDataset in DataLoader workers
(a reliable stream: no scene is lost, generators stay within the window), and prints the loss, the
scenes per second the generators produce and the learner consumes, and the reuse factor; on a
live bus its progress also goes out on STACKGEN_LEARNER (stackgen.LearnerStatus), for
stackgen-monitor.
--record LOG keeps every sample's scene, in order, in an LCM log (and the run's settings in
LOG.train.json); --replay LOG trains again on exactly those samples, with the same batches and,
on the same machine and device, the same losses. --mix DIR mixes labelled real images in at
--mix-fraction; --eval DIR scores the model (the paper's MIoU, COCO mask AP) every
--eval-every iterations and at the end. --nproc N trains with N processes under
torch.distributed (DDP; gloo on the CPU, NCCL on CUDA), each rank on its own share of the scenes,
as torchrun would start them (the script also runs under torchrun itself: it reads RANK,
WORLD_SIZE, MASTER_ADDR and MASTER_PORT).
"""

import argparse
import json
import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import zlib

import toolcli

# OpenMP threads that spin while they wait starve the generators on a small machine; set before
# torch loads its OpenMP runtime
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

PROGRAM = "train-live"
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# settings recorded beside a log and taken again by --replay
REPLAYED = ("iterations", "workers", "batch_size", "seed", "reuse", "reuse_buffer", "augment",
            "gray", "backbone", "num_classes", "rois", "lr", "threads", "min_visib_fract", "mix",
            "mix_fraction")


def fail(message):
    toolcli.fail(PROGRAM, message)


positive_int = toolcli.whole_number(1)
non_negative_int = toolcli.whole_number(0)


def positive_float(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError("wants a number, got %r" % text) from None
    if not (value > 0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError("wants a number > 0, got %r" % text)
    return value


def fraction_below_one(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError("wants a number in [0, 1), got %r" % text) from None
    if not 0 <= value < 1:
        raise argparse.ArgumentTypeError("wants a number in [0, 1), got %r" % text)
    return value


def parse_args(argv):
    parser = toolcli.Parser(
        PROGRAM,
        prog="tools/train-live",
        description="Trains torchvision's Mask R-CNN (weights=None) live on stackgen scenes.",
        epilog="Exit status: 0 done, 1 error, 2 bad command line.")
    source = parser.add_argument_group("where scenes come from")
    source.add_argument("--generators", type=non_negative_int, default=1,
                        help="generators to start, ids 0..N-1 (default 1); 0 with --attach")
    source.add_argument("--attach", action="store_true",
                        help="start none: train on the generators already on --lcm-url")
    source.add_argument("--config", default=os.path.join(ROOT, "config", "default.pbtxt"),
                        help="generator config (default config/default.pbtxt)")
    source.add_argument("--scene-seed", type=non_negative_int, default=0,
                        help="the generators' base seed (default 0)")
    source.add_argument("--lcm-url", default=None,
                        help="the bus (default: a free port of its own when starting generators,"
                             " $STACKGEN_LCM_URL or the default bus with --attach)")
    source.add_argument("--best-effort", action="store_true",
                        help="a best-effort stream: never hold the generators back, skip what "
                             "the learner is too slow for (default: reliable)")
    source.add_argument("--window", type=positive_int, default=8,
                        help="reliable: scenes a generator may run ahead (default 8)")
    source.add_argument("--bus-key-file", metavar="FILE", default=None,
                        help="the bus key of the generators and the stream (default: "
                             "$STACKGEN_BUS_KEY_FILE, else this user's ~/.config/stackgen/bus.key,"
                             " made on first use)")
    source.add_argument("--open-bus", action="store_true",
                        help="no bus key: nothing signed, every sender trusted")
    source.add_argument("--record", metavar="LOG",
                        help="keep every sample's scene in this LCM log (must not exist)")
    source.add_argument("--replay", metavar="LOG",
                        help="train on a log made with --record instead of generators")
    # (tools/train-live sets STACKGEN_BIN_DIR: build/bin, or /usr/bin for the .deb's)
    source.add_argument("--stackgen", default=os.path.join(os.environ.get(
                            "STACKGEN_BIN_DIR", os.path.join(ROOT, "build", "bin")), "stackgen"),
                        help=argparse.SUPPRESS)
    training = parser.add_argument_group("training")
    training.add_argument("--iterations", type=positive_int, default=100,
                          help="optimiser steps (default 100)")
    training.add_argument("--batch-size", type=positive_int, default=2,
                          help="images per step (default 2)")
    training.add_argument("--workers", type=non_negative_int, default=1,
                          help="DataLoader workers, each with its own shard (default 1)")
    training.add_argument("--reuse", type=positive_int, default=4,
                          help="use each scene up to R times while no new one waits (default 4)")
    training.add_argument("--reuse-buffer", type=positive_int, default=32,
                          help="recent scenes reuse draws from, per worker (default 32)")
    training.add_argument("--no-augment", dest="augment", action="store_false",
                          help="no augmentation (default: stackgen.augment.Augment())")
    training.add_argument("--gray", action="store_true",
                          help="train on gray images (1 channel in, as the paper found good "
                               "enough for monochrome parts)")
    training.add_argument("--min-visib-fract", type=float, default=0.3,
                          help="objects less visible after augmentation become ignore regions "
                               "(default 0.3)")
    training.add_argument("--backbone", choices=("resnet50", "resnet18"), default="resnet50",
                          help="ResNet-FPN backbone, random init (default resnet50)")
    training.add_argument("--num-classes", type=positive_int, default=8,
                          help="classes including background; class ids must be below "
                               "(default 8)")
    training.add_argument("--rois", type=positive_int, default=64,
                          help="RoIs sampled per image for the box and mask heads (torchvision's "
                               "default 512 is for 100 objects; a bin of 12 parts needs far "
                               "fewer, and the mask head's cost grows with them; default 64)")
    training.add_argument("--lr", type=positive_float, default=0.01,
                          help="SGD learning rate after a linear warm-up (default 0.01)")
    training.add_argument("--seed", type=non_negative_int, default=0,
                          help="model init and augmentation seed (default 0)")
    training.add_argument("--mix", metavar="DIR",
                          help="mix labelled real images in: a COCO folder (annotations.json) "
                               "or labelme files, augmented as the scenes")
    training.add_argument("--mix-fraction", type=fraction_below_one, default=None,
                          help="the share of real images among the samples, in [0, 1) "
                               "(default 0.1 with --mix)")
    training.add_argument("--nproc", type=positive_int, default=1,
                          help="training processes (DDP ranks), each with --workers workers on "
                               "its own share of the scenes (default 1)")
    training.add_argument("--device", default="cpu", help="cpu (default), cuda, cuda:1, ...")
    training.add_argument("--threads", type=positive_int, default=os.cpu_count() or 1,
                          help="torch CPU threads (default: the cores)")
    output = parser.add_argument_group("output")
    output.add_argument("--print-every", type=positive_int, default=10,
                        help="a progress line every N iterations (default 10)")
    output.add_argument("--loss-csv", metavar="FILE",
                        help="write per step: iteration, loss, a CRC-32 of the batch (images, "
                             "boxes, labels, masks) and each loss term, to FILE")
    output.add_argument("--save", metavar="FILE", help="save the model's state_dict at the end")
    output.add_argument("--eval", metavar="DIR",
                        help="score the model on a labelled folder (COCO or labelme) held out "
                             "from training: the paper's MIoU and COCO mask AP")
    output.add_argument("--eval-every", type=positive_int, default=None, metavar="N",
                        help="with --eval: every N iterations, and at the end (default: at the "
                             "end only)")
    args = parser.parse_args(argv)
    given = {action.dest for action in parser._actions
             if any(option in argv or any(a.startswith(option + "=") for a in argv)
                    for option in action.option_strings)}
    if args.record and args.replay:
        parser.error("--record and --replay exclude each other")
    if args.bus_key_file and args.open_bus:
        parser.error("--bus-key-file and --open-bus exclude each other")
    if args.replay and args.attach:
        parser.error("--replay and --attach exclude each other")
    if not args.attach and not args.replay and args.generators == 0:
        parser.error("--generators 0 needs --attach")
    if args.mix_fraction is not None and not args.mix:
        parser.error("--mix-fraction needs --mix DIR")
    if args.eval_every is not None and not args.eval:
        parser.error("--eval-every needs --eval DIR")
    if args.nproc > 1 and (args.record or args.replay):
        parser.error("--%s takes one process: one log cannot hold the samples of %d ranks" %
                     ("record" if args.record else "replay", args.nproc))
    if not 0 <= args.min_visib_fract <= 1:
        parser.error("--min-visib-fract wants a number in [0, 1], got %r" % args.min_visib_fract)
    return args, given


def free_udp_port():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("", 0))
        return probe.getsockname()[1]


def build_model(args, channels, height, width):
    import torch
    from torchvision.models.detection import MaskRCNN, maskrcnn_resnet50_fpn
    from torchvision.models.detection.backbone_utils import resnet_fpn_backbone

    torch.manual_seed(args.seed)
    mean, std = ([0.485, 0.456, 0.406], [0.229, 0.224, 0.225]) if channels == 3 else ([0.45], [0.25])
    # the images' own size: no resizing in the model
    common = dict(num_classes=args.num_classes, min_size=min(height, width),
                  box_batch_size_per_image=args.rois, rpn_post_nms_top_n_train=1000,
                  max_size=max(height, width), image_mean=mean, image_std=std)
    if args.backbone == "resnet50":
        model = maskrcnn_resnet50_fpn(weights=None, weights_backbone=None, **common)
    else:
        backbone = resnet_fpn_backbone(backbone_name="resnet18", weights=None, trainable_layers=5)
        model = MaskRCNN(backbone, **common)
    if channels == 1:
        body = model.backbone.body
        body.conv1 = torch.nn.Conv2d(1, 64, kernel_size=7, stride=2, padding=3, bias=False)
    return model


# a child's command line, so that it gets SIGTERM when train-live dies, by SIGKILL too: no
# generator or rank outlives it (setpriv from util-linux sets PR_SET_PDEATHSIG, then runs the
# command in its place; not Popen's preexec_fn, which may deadlock in a process with threads)
DIE_WITH_PARENT = ["setpriv", "--pdeathsig", "TERM", "--"]


def start_generators(args, url, logs):
    """The generators train-live runs itself (none with --replay or --attach): (process, log)."""
    generators = []
    for generator_id in range(0 if args.replay or args.attach else args.generators):
        log = open(os.path.join(logs, "stackgen%d.log" % generator_id), "w")
        command = DIE_WITH_PARENT + [
            args.stackgen, "--config", args.config, "--seed", str(args.scene_seed),
            "--generator-id", str(generator_id), "--lcm-url", url] + (
                ["--open-bus"] if args.open_bus else
                ["--bus-key-file", args.bus_key_file] if args.bus_key_file else [])
        generators.append((subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT),
                           log.name))
    return generators


def check_generators(generators):
    """Fails, with the last line of its log, when a generator stopped."""
    for process, log in generators:
        if process.poll() is not None:
            with open(log) as file:
                lines = file.read().strip().splitlines()
            fail("a generator stopped (exit %d): %s" % (process.returncode,
                                                        lines[-1] if lines else log))


def stop(processes):
    for process in processes:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
    for process in processes:
        try:
            process.wait(timeout=15)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def distributed():
    """(rank, world size, local rank) from torch.distributed's environment (torchrun's, or
    --nproc's); (0, 1, 0) without one."""
    try:
        world = int(os.environ.get("WORLD_SIZE", "1"))
        rank = int(os.environ.get("RANK", "0"))
        local = int(os.environ.get("LOCAL_RANK", str(rank)))
    except ValueError:
        fail("WORLD_SIZE, RANK and LOCAL_RANK must be whole numbers, got %r, %r, %r" % (
            os.environ.get("WORLD_SIZE"), os.environ.get("RANK"), os.environ.get("LOCAL_RANK")))
    if world > 1 and not 0 <= rank < world:
        fail("RANK %d is not one of WORLD_SIZE %d" % (rank, world))
    return rank, world, local


def without_flag(argv, flag):
    """argv without `flag` and its value (as "--flag V" or "--flag=V")."""
    out, skip = [], False
    for arg in argv:
        if skip:
            skip = False
        elif arg == flag:
            skip = True
        elif not arg.startswith(flag + "="):
            out.append(arg)
    return out


def run_ranks(args, argv, url, generators, logs):
    """--nproc N: this script N times, as ranks 0..N-1 of one job (torchrun's environment:
    RANK, LOCAL_RANK, WORLD_SIZE, MASTER_ADDR, MASTER_PORT), attached to the generators on
    `url`. Rank 0 prints; the others write logs, shown when one fails. Returns the exit status."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    child = without_flag(argv, "--nproc") + ["--attach", "--lcm-url", url]
    ranks = []
    for rank in range(args.nproc):
        env = dict(os.environ, RANK=str(rank), LOCAL_RANK=str(rank), WORLD_SIZE=str(args.nproc),
                   LOCAL_WORLD_SIZE=str(args.nproc), MASTER_ADDR="127.0.0.1",
                   MASTER_PORT=str(port))
        log = None if rank == 0 else os.path.join(logs, "rank%d.log" % rank)
        out = open(log, "w") if log else None
        ranks.append((subprocess.Popen(DIE_WITH_PARENT + [sys.executable,
                                                          os.path.abspath(__file__)] + child,
                                       env=env, stdout=out, stderr=subprocess.STDOUT if out else
                                       None), log))
    try:
        while True:
            check_generators(generators)
            for rank, (process, log) in enumerate(ranks):
                if process.poll() not in (None, 0):
                    stop([p for p, _ in ranks])
                    tail = ""
                    if log:
                        with open(log) as file:
                            lines = file.read().strip().splitlines()
                        tail = ": " + " | ".join(lines[-3:]) if lines else ""
                    fail("rank %d of %d stopped (exit %d)%s" % (rank, args.nproc,
                                                               process.returncode, tail))
            if all(process.poll() == 0 for process, _ in ranks):
                return 0
            time.sleep(0.2)
    finally:
        stop([p for p, _ in ranks])


def run_eval(args, model, eval_set, device, iteration):
    import stackgen.torch as sgt

    start = time.monotonic()
    result = sgt.evaluate(model, eval_set, device=device, grayscale=args.gray)
    print("%s: eval at iteration %d on %s (%d images): MIoU %.3f (TP %d, FP %d, FN %d), mask AP "
          "%.3f, AP50 %.3f, AP75 %.3f, box AP %.3f (%.1f s)" % (
              PROGRAM, iteration, args.eval, result["images"], result["miou"], result["tp"],
              result["fp"], result["fn"], result["ap"], result["ap50"], result["ap75"],
              result["box_ap"], time.monotonic() - start), flush=True)
    return result


def apply_recording(args, given):
    """--replay takes the recorded run's settings unless given again."""
    sidecar = args.replay + ".train.json"
    if not os.path.exists(sidecar):
        return
    with open(sidecar) as file:
        recorded = json.load(file)
    for key in REPLAYED:
        if key not in recorded:
            continue
        if key in given and getattr(args, key) != recorded[key]:
            print("%s: warning: --%s %s differs from the recording's %s: the batches "
                  "or losses will differ" % (PROGRAM, key.replace("_", "-"),
                                             getattr(args, key), recorded[key]))
        elif key not in given:
            setattr(args, key, recorded[key])


def choose_device(args, world, local_rank):
    """The torch device of this rank, after the checks of --device against the ranks."""
    import torch

    if args.nproc > 1 and world > 1:
        fail("--nproc %d under torchrun (WORLD_SIZE %d): let one of them start the ranks" % (
            args.nproc, world))
    if args.device.startswith("cuda") and not torch.cuda.is_available():
        fail("--device %s: torch has no CUDA device here (torch %s)" % (args.device,
                                                                       torch.__version__))
    try:
        device = torch.device(args.device)
    except RuntimeError as error:
        fail("--device %s: %s" % (args.device, error))
    if device.type == "cuda" and (args.nproc > 1 or world > 1):
        # one GPU per rank, rank r on cuda:r (NCCL's collectives run on the current device)
        if device.index is not None:
            fail("--device %s with several ranks: pass --device cuda, each rank takes its own "
                 "GPU" % args.device)
        ranks = max(args.nproc, world)
        if ranks > torch.cuda.device_count():
            fail("%d ranks on CUDA need %d GPUs; torch sees %d" % (
                ranks, ranks, torch.cuda.device_count()))
        if world > 1:
            device = torch.device("cuda", local_rank)
            torch.cuda.set_device(device)
    return device


def open_labelled_sets(args):
    """The --mix and --eval folders (None where not given)."""
    from stackgen.coco import open_labelled_folder

    sets = []
    for flag, folder in (("--mix", args.mix), ("--eval", args.eval)):
        try:
            sets.append(open_labelled_folder(folder) if folder else None)
        except ValueError as error:
            fail("%s: %s" % (flag, error))
    return sets


def bus_url(args):
    """The bus to train from: the --replay log, the --attach'ed bus, or one of the run's own."""
    import stackgen

    url = args.lcm_url
    if args.replay:
        url = "file://" + os.path.abspath(args.replay)
    elif not args.attach:
        if not os.path.exists(args.config):
            fail("--config %s: no such file" % args.config)
        if not os.access(args.stackgen, os.X_OK):
            fail("%s is not built: run tools/train-live (it builds it)" % args.stackgen)
        url = url or "udpm://239.255.76.67:%d?ttl=0&recv_buf_size=4194304" % free_udp_port()
    return stackgen.resolve_lcm_url(url or "")


def open_dataset(args, url, augment, mix_set):
    """The stream of scenes (and mixed-in photos) the loader draws from."""
    import stackgen.torch as sgt

    try:
        return sgt.StreamDataset(
            url, reliable=not args.best_effort, window=args.window, reuse=1 if args.replay
            else args.reuse, reuse_buffer=args.reuse_buffer, grayscale=args.gray,
            augment=augment, min_visib_fract=args.min_visib_fract, seed=args.seed,
            record=args.record, replay=bool(args.replay),
            # no timeout: a rank whose scenes wait behind rank 0's evaluation must not give up;
            # the stream says what it waits for, and ends when the generators' runs end
            timeout=None, name="train-live",
            bus_key_file=args.bus_key_file, open_bus=args.open_bus,
            mix=mix_set, mix_fraction=args.mix_fraction)
    except ValueError as error:
        fail(str(error))


def print_start(args, url, generators, augment, dataset, world):
    print("%s: %s, %s stream, %d workers, batch %d, reuse up to %d, %s, %s backbone, "
          "%s%s%s" % (
              PROGRAM, "replaying " + args.replay if args.replay else
              "%d generators on %s" % (len(generators), url) if generators else
              "attached to " + url,
              "best-effort" if args.best_effort else "reliable", args.workers,
              args.batch_size, 1 if args.replay else args.reuse,
              "augmented" if augment else "not augmented", args.backbone,
              "gray" if args.gray else "rgb",
              ", mixing %.0f %% real images from %s (%d)" % (
                  100 * dataset.mix_fraction, args.mix, len(dataset.mix))
              if args.mix else "",
              ", rank 0 of %d" % world if world > 1 else ""), flush=True)


class Training:
    """The model, its optimiser and what the loop has seen, made at the first batch."""

    def __init__(self, args, device, world, rank, monitor, eval_set):
        import stackgen.torch as sgt

        self.args, self.device, self.world, self.rank = args, device, world, rank
        self.monitor, self.eval_set = monitor, eval_set
        # rank 0 on a live bus: its progress on STACKGEN_LEARNER (stackgen-monitor shows it)
        self.learner = None
        self.meter = sgt.ReuseMeter()
        self.model = self.optimizer = self.parameters = None
        self.losses = []
        self.iteration = 0
        self.csv = open(args.loss_csv, "w") if args.loss_csv and rank == 0 else None
        self.start = self.last_time = time.monotonic()
        self.last_scenes = 0
        self.last_produced = None
        self.warmup = min(50, args.iterations)

    def build(self, images, raw_targets):
        """The model, sized by a scene, not a mixed-in photo of another size (the first batch
        without a scene falls back to its first image)."""
        import torch

        scenes = [image for image, target in zip(images, raw_targets)
                  if int(target["scene"][0]) >= 0]
        channels, height, width = (scenes or images)[0].shape
        self.model = build_model(self.args, channels, height, width).to(self.device)
        self.model.train()
        if self.world > 1:
            self.model = torch.nn.parallel.DistributedDataParallel(
                self.model, device_ids=[self.device.index] if self.device.type == "cuda"
                else None)
        self.parameters = [p for p in self.model.parameters() if p.requires_grad]
        self.optimizer = torch.optim.SGD(self.parameters, lr=self.args.lr, momentum=0.9,
                                         weight_decay=1e-4)

    def step(self, images, targets):
        """One optimiser step on a batch (ignore regions already left out); the loss line of
        --loss-csv with a digest of the batch, so that two runs can be compared step by step."""
        import torch

        args = self.args
        # linear warm-up, then the set rate
        for group in self.optimizer.param_groups:
            group["lr"] = args.lr * min(1.0, 0.001 + (1 - 0.001) * self.iteration / self.warmup)
        digest = 0
        if self.csv:
            for image, target in zip(images, targets):
                digest = zlib.crc32(image.numpy().tobytes(), digest)
                for key in ("boxes", "labels", "masks"):
                    digest = zlib.crc32(target[key].numpy().tobytes(), digest)
        images = [image.to(self.device) for image in images]
        targets = [{k: v.to(self.device) for k, v in t.items()
                    if k in ("boxes", "labels", "masks")} for t in targets]
        loss_dict = self.model(images, targets)
        loss = sum(loss_dict.values())
        self.optimizer.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(self.parameters, 10.0)
        self.optimizer.step()
        self.iteration += 1
        value = float(loss)
        if not math.isfinite(value):
            fail("the loss is %s at iteration %d: lower --lr" % (value, self.iteration))
        self.losses.append(value)
        if self.csv:
            self.csv.write("%d,%.9g,%08x,%s\n" % (self.iteration, value, digest, ",".join(
                "%s=%.9g" % (k, float(v)) for k, v in sorted(loss_dict.items()))))
        return value, loss_dict

    def print_progress(self, value, loss_dict):
        now = time.monotonic()
        seconds = max(now - self.last_time, 1e-9)
        produced = ""
        if self.monitor is not None:
            total = sum(s["scenes"] for s in self.monitor.latest("stackgen"))
            if self.last_produced is not None:
                produced = "produced %.2f scenes/s, " % ((total - self.last_produced) / seconds)
            self.last_produced = total
        parts = " ".join("%s %.3f" % (k.replace("loss_", ""), float(v))
                         for k, v in sorted(loss_dict.items()))
        print("iter %d/%d loss %.4f (%s) | %sconsumed %.2f scenes/s, reuse %.2f | "
              "%.2f s/iter" % (self.iteration, self.args.iterations, value, parts, produced,
                               (self.meter.scenes - self.last_scenes) / seconds,
                               self.meter.factor, seconds / self.args.print_every), flush=True)
        self.last_time, self.last_scenes = now, self.meter.scenes

    def run(self, loader, generators):
        """Batches until --iterations, with the progress line and the periodic --eval."""
        import stackgen.torch as sgt

        args = self.args
        for images, targets in loader:
            check_generators(generators)
            self.meter.update(targets)
            raw_targets = targets
            targets = [sgt.without_ignore_regions(t) for t in targets]
            for target in targets:
                if len(target["labels"]) and int(target["labels"].max()) >= args.num_classes:
                    fail("class id %d seen: pass --num-classes %d or more" % (
                        int(target["labels"].max()), int(target["labels"].max()) + 1))
            if self.model is None:
                self.build(images, raw_targets)
            value, loss_dict = self.step(images, targets)
            if self.learner is not None:
                self.learner.report(self.iteration, value, scenes_taken=self.meter.scenes,
                                    target_steps=args.iterations, samples=self.meter.samples)
            if self.rank == 0 and (self.iteration % args.print_every == 0 or
                                   self.iteration == args.iterations):
                self.print_progress(value, loss_dict)
            if (self.rank == 0 and self.eval_set is not None and args.eval_every and
                    self.iteration % args.eval_every == 0 and self.iteration < args.iterations):
                run_eval(args, getattr(self.model, "module", self.model), self.eval_set,
                         self.device, self.iteration)
            if self.iteration >= args.iterations:
                break
        if self.csv:
            self.csv.close()
        if not self.losses:
            fail("no batch arrived" + (" (the log holds no scenes)" if args.replay else ""))

    def report_ranks(self):
        """What every rank took: their scenes are disjoint, and DDP kept the models equal."""
        import torch

        world, meter = self.world, self.meter
        shares = [None] * world
        torch.distributed.all_gather_object(shares, (
            meter.samples, meter.real, sorted(meter.seen), zlib.crc32(b"".join(
                p.detach().cpu().numpy().tobytes() for p in self.model.parameters()))))
        if self.rank == 0:
            seen = [set(map(tuple, share[2])) for share in shares]
            union = set().union(*seen)
            print("%s: %d ranks: %d samples of %d distinct scenes, %s; parameters %s" % (
                PROGRAM, world, sum(share[0] for share in shares), len(union),
                "none on two ranks" if len(union) == sum(map(len, seen)) else
                "%d on two ranks or more" % (sum(map(len, seen)) - len(union)),
                "equal on every rank" if len({share[3] for share in shares}) == 1 else
                "DIFFER between ranks"), flush=True)

    def report_end(self):
        """Rank 0's summary, the last --eval, the recording's name and --save."""
        import numpy as np
        import torch

        args, meter, losses = self.args, self.meter, self.losses
        elapsed = time.monotonic() - self.start
        first, last = losses[:10], losses[-10:]
        print("%s: %d iterations in %.1f s; %d samples of %d distinct scenes (reuse %.2f)%s; "
              "loss first %d mean %.4f, last %d mean %.4f" % (
                  PROGRAM, self.iteration, elapsed, meter.samples, meter.scenes, meter.factor,
                  ", %d real images" % meter.real if args.mix else "",
                  len(first), float(np.mean(first)), len(last), float(np.mean(last))),
              flush=True)
        model = getattr(self.model, "module", self.model)
        if self.eval_set is not None:
            run_eval(args, model, self.eval_set, self.device, self.iteration)
        if args.record:
            print("%s: recorded %s; train on it again: tools/train-live --replay %s" %
                  (PROGRAM, args.record, args.record))
        if args.save:
            torch.save(model.state_dict(), args.save)


def main(argv):
    args, given = parse_args(argv)
    import torch
    from torch.utils.data import DataLoader

    import stackgen
    import stackgen.torch as sgt

    stackgen.set_program_name(PROGRAM)
    if args.replay:
        apply_recording(args, given)
    rank, world, local_rank = distributed()
    device = choose_device(args, world, local_rank)
    mix_set, eval_set = open_labelled_sets(args)
    torch.set_num_threads(args.threads)
    torch.use_deterministic_algorithms(True, warn_only=True)

    generators = []
    logs = tempfile.mkdtemp(prefix="stackgen-train-live.")
    try:
        url = bus_url(args)
        augment = sgt.Augment() if args.augment else None
        if world > 1:
            torch.distributed.init_process_group("nccl" if device.type == "cuda" else "gloo")
        dataset = open_dataset(args, url, augment, mix_set)
        if args.record:
            settings = {key: getattr(args, key) for key in REPLAYED}
            with open(args.record + ".train.json", "w") as file:
                json.dump(settings, file, indent=1, sort_keys=True)

        # the generators, after the bus and the record file were found good
        generators = start_generators(args, url, logs)
        if args.nproc > 1:
            print("%s: %d ranks (DDP, %s), %s" % (
                PROGRAM, args.nproc, "nccl" if device.type == "cuda" else "gloo",
                "%d generators on %s" % (len(generators), url) if generators else
                "attached to " + url), flush=True)
            return run_ranks(args, argv, url, generators, logs)
        monitor = None if args.replay or rank > 0 else stackgen.StatusMonitor(
            url, bus_key_file=args.bus_key_file, open_bus=args.open_bus)
        if rank == 0:
            print_start(args, url, generators, augment, dataset, world)

        loader = DataLoader(dataset, batch_size=args.batch_size, num_workers=args.workers,
                            collate_fn=sgt.collate,
                            persistent_workers=False)
        training = Training(args, device, world, rank, monitor, eval_set)
        if monitor is not None:
            training.learner = stackgen.LearnerStatus(
                url, process=PROGRAM, bus_key_file=args.bus_key_file, open_bus=args.open_bus)
        training.run(loader, generators)
        if training.learner is not None:
            training.learner.close(ended=True)
        if world > 1:
            training.report_ranks()
        if rank == 0:
            training.report_end()
        if world > 1:
            torch.distributed.barrier()
            torch.distributed.destroy_process_group()
        return 0
    except stackgen.StreamError as error:
        fail(str(error))
    except KeyboardInterrupt:
        print("%s: interrupted" % PROGRAM)
        return 1
    finally:
        stop([process for process, _ in generators])
        shutil.rmtree(logs, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
