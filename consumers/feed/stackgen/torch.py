"""PyTorch on the stream: `StreamDataset` yields (image, target) pairs in torchvision's detection
format straight from the bus (or a log), for a live training loop.

    from torch.utils.data import DataLoader
    import stackgen.torch as sgt

    dataset = sgt.StreamDataset(lcm_url=URL, reliable=True, reuse=4, augment=True, seed=0)
    loader = DataLoader(dataset, batch_size=2, num_workers=2, collate_fn=sgt.collate)
    for images, targets in loader:
        losses = model(list(images), [sgt.without_ignore_regions(t) for t in targets])

Each DataLoader worker opens its own stream and takes one shard of the seqs (seq % workers), so no
scene reaches two workers; a reliable stream misses none. Under torch.distributed (DDP) every
rank takes its own shards (rank x workers), so no scene reaches two ranks either. See
StreamDataset for the target.
"""

from __future__ import annotations

import math
import os
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple, Union

import cv2
import numpy as np
import torch
from torch.utils.data import IterableDataset, get_worker_info

import stackgen
from stackgen.augment import Augment, exact_labels
from stackgen.coco import open_labelled_folder

__all__ = ["StreamDataset", "collate", "without_ignore_regions", "ReuseMeter", "Augment",
           "evaluate"]

# the most shards (ranks x workers) the seqs split into (session/delivery.h kMaxShards)
MAX_WORKERS = 256


def _rank_and_world(rank, world_size):
    """(rank, world size): the arguments when given, else torch.distributed's when it is
    initialised, else (0, 1)."""
    if (rank is None) != (world_size is None):
        raise ValueError("rank and world_size come together (or neither: torch.distributed's)")
    if rank is not None:
        for name, value in (("rank", rank), ("world_size", world_size)):
            if isinstance(value, bool) or not isinstance(value, int):
                raise ValueError("%s must be a whole number, got %r" % (name, value))
        if not 0 <= rank < world_size:
            raise ValueError("rank must be in 0..world_size-1, got rank %d of %d" %
                             (rank, world_size))
        return rank, world_size
    distributed = torch.distributed
    if distributed.is_available() and distributed.is_initialized():
        return distributed.get_rank(), distributed.get_world_size()
    return 0, 1

_SEED_MASK = (1 << 64) - 1
# marks the draws of real images (StreamDataset's mix) apart from the scenes'
_REAL_TAG = 0x8EA1


def collate(batch: List[Tuple[torch.Tensor, Dict[str, torch.Tensor]]]
            ) -> Tuple[Tuple[torch.Tensor, ...], Tuple[Dict[str, torch.Tensor], ...]]:
    """The detection collate: the batch's images and targets as two tuples.

    Args:
        batch: (image, target) pairs, as StreamDataset yields them.

    Returns:
        A tuple of images and a tuple of targets (sizes may differ).
    """
    return tuple(zip(*batch))


def without_ignore_regions(target: Dict[str, torch.Tensor]) -> Dict[str, torch.Tensor]:
    """The target without its ignore regions (iscrowd 1).

    Torchvision's detection models want it so for training: they have no notion of an ignore
    region.

    Args:
        target: a target of StreamDataset.

    Returns:
        A new dict: the per-instance entries without the ignore regions, the others as they are.
    """
    keep = target["iscrowd"] == 0
    return {key: (value[keep] if _per_instance(key) else value) for key, value in target.items()}


_PER_INSTANCE = ("boxes", "labels", "masks", "iscrowd", "area", "visib_fract", "px_count_all",
                 "px_count_visib", "instance_ids", "camera_from_object", "world_from_object")


def _per_instance(key):
    return key in _PER_INSTANCE


def evaluate(model: torch.nn.Module, dataset: Union[str, os.PathLike, Any],
             device: Union[str, torch.device] = "cpu", score_threshold: float = 0.5,
             grayscale: bool = False) -> Dict[str, float]:
    """Scores a torchvision instance-segmentation model (Mask R-CNN and the like: a list of
    images in, dicts with scores, boxes and masks out) on labelled images: the seed paper's MIoU
    and COCO mask and box AP.

    Args:
        model: the model; put in eval mode for the scoring and back in the mode it was in.
        dataset: a labelled folder (COCO or labelme: stackgen.coco.open_labelled_folder) or a
            dataset object with len(), image(i) and target(i) (stackgen.coco.CocoDataset).
        device: where the images go (the model's device).
        score_threshold: predictions below it do not count for the paper's score.
        grayscale: the model takes one channel (the images are converted).

    Returns:
        stackgen.metrics.DetectionScores.result(): miou, tp, fp, fn, ap, ap50, ap75 (mask AP),
        box_ap, box_ap50, box_ap75, images.
    """
    from stackgen.metrics import DetectionScores

    if isinstance(dataset, (str, os.PathLike)):
        dataset = open_labelled_folder(os.fspath(dataset))
    scores = DetectionScores(score_threshold=score_threshold)
    was_training = model.training
    model.eval()
    try:
        with torch.no_grad():
            for index in range(len(dataset)):
                image = dataset.image(index)
                truth, _, crowd = dataset.target(index)
                if grayscale:
                    image = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)[:, :, None]
                tensor = torch.from_numpy(np.ascontiguousarray(image)).permute(2, 0, 1)
                output = model([tensor.float().div(255).to(device)])[0]
                masks = (output["masks"][:, 0] > 0.5).cpu().numpy()
                scores.update(output["scores"].cpu().numpy(), masks, truth.astype(bool), crowd,
                              boxes=output["boxes"].cpu().numpy())
    finally:
        model.train(was_training)
    return scores.result()


class ReuseMeter:
    """Counts what a training loop took: samples of scenes, distinct scenes, and reuse.

    The reuse factor achieved is samples per distinct scene; real images mixed in
    (StreamDataset's mix) are counted apart, in `real`. Feed it each batch's targets.

    Attributes:
        samples: samples of scenes taken.
        real: real images taken.
    """

    def __init__(self):
        self.samples = 0
        self.real = 0
        self._scenes = set()

    def update(self, targets):
        """Counts one batch.

        Args:
            targets: the batch's targets (StreamDataset's), each with its "scene" entry.
        """
        for target in targets:
            generator_id, seq, _ = (int(v) for v in target["scene"])
            if generator_id < 0:
                self.real += 1
                continue
            self.samples += 1
            self._scenes.add((generator_id, seq))

    @property
    def scenes(self):
        """int: the distinct scenes taken."""
        return len(self._scenes)

    @property
    def seen(self):
        """frozenset: the (generator_id, seq) of every distinct scene taken."""
        return frozenset(self._scenes)

    @property
    def factor(self):
        """float: the reuse factor achieved, samples per distinct scene."""
        return self.samples / max(1, len(self._scenes))


def _open_mix(mix, mix_fraction):
    """StreamDataset's mix (a folder is opened) and mix_fraction (default 0.1), checked."""
    if mix is None:
        if mix_fraction is not None:
            raise ValueError("mix_fraction needs mix: the real images to mix in")
        return None, None
    if isinstance(mix, (str, os.PathLike)):
        mix = open_labelled_folder(os.fspath(mix))
    elif not all(hasattr(mix, name) for name in ("__len__", "image", "target")):
        raise ValueError("mix must be a folder or a dataset with len(), image(i) and "
                         "target(i), got %r" % (mix,))
    if len(mix) == 0:
        raise ValueError("mix: %s holds no images" % getattr(mix, "folder", mix))
    mix_fraction = 0.1 if mix_fraction is None else mix_fraction
    if (isinstance(mix_fraction, bool) or not isinstance(mix_fraction, (int, float)) or
            not 0 <= mix_fraction < 1):
        raise ValueError("mix_fraction must be in [0, 1), got %r" % (mix_fraction,))
    return mix, mix_fraction


def _create_record(record):
    """The record file, created empty for the workers to append to; an existing one refused."""
    try:
        os.close(os.open(record, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644))
    except FileExistsError:
        raise stackgen.StreamError("record: %s exists already; give another file" %
                                   record) from None
    except OSError as error:
        raise stackgen.StreamError("record: cannot create %s: %s" %
                                   (record, error.strerror)) from None
    return record


class StreamDataset(IterableDataset):
    """(image, target) pairs from a live stackgen bus or a log, for torchvision detection models.

    Usable with DataLoader(num_workers=k) (k <= 256): each worker opens its own stream on one
    shard of the seqs.

    image: float32 (3, H, W) in [0, 1] (RGB; a gray camera's image repeated), or (1, H, W) with
        grayscale=True (a colour image converted), the paper's option for monochrome parts.
    target (torch tensors; M instances: those the generator annotated or kept as ignore regions
        that still have a visible pixel):
        boxes (M, 4) float32 XYXY of the visible pixels; labels (M,) int64 class ids; masks
        (M, H, W) uint8 visible masks; iscrowd (M,) int64 (1: an ignore region); area (M,)
        float32 visible pixels; visib_fract (M,) float32; px_count_all, px_count_visib,
        instance_ids (M,) int64; camera_from_object, world_from_object (M, 4, 4) float64
        (millimetres, OpenCV camera frame); K (3, 3) float64 (A @ K after augmentation);
        image_id () int64 (generator_id * 10^8 + seq + 1, as stackgen-coco); scene (3,) int64
        (generator_id, seq, use); with depth=True also depth_mm (H, W) float32.
    Torchvision's models want the ignore regions out: without_ignore_regions(target).

    Args:
        lcm_url: the bus or log, as stackgen.Stream.
        reliable: a reliable consumer or best effort, as stackgen.Stream.
        window: as stackgen.Stream.
        generator_ids: as stackgen.Stream.
        timeout: as stackgen.Stream.
        count: scenes in all (split between the workers), 0: no end.
        reuse: each scene is used up to `reuse` times (default 1: once). A new scene is always
            taken first; when none is waiting, a scene of the last `reuse_buffer` that has been
            used fewer times is drawn at random instead, so a learner faster than the
            generators stays busy. The factor achieved: ReuseMeter, or target["scene"][2] (the
            use).
        reuse_buffer: the recent scenes that `reuse` draws from (default 32).
        grayscale: one-channel images (1, H, W), a colour image converted: the paper's option
            for monochrome parts.
        augment: None or False (default): none; True: Augment() with its defaults; or an
            Augment.
        min_visib_fract: an annotated object less visible than this after augmentation becomes
            an ignore region (default 0.3, the paper's threshold).
        min_visible_px: so does one with fewer visible pixels (default 16, as the generator's
            annotation.min_visible_px: a zoom or crop can shrink a part below it).
        seed: augmentation is drawn from (seed, generator_id, seq, use, scene seed): the same
            log and seed give the same samples, whichever worker makes them.
        record: a path: every sample's scene is appended to this LCM log (STACKGEN_SCENE, one
            event per use, in the order each worker hands them out); the file must not exist.
        replay: the URL is a log made with `record`: every event is one sample, the n-th repeat
            of a scene its n-th use (reuse must be 1). With the same workers, batch size and
            seed a training run sees the same batches as the recorded one.
        depth: add depth_mm to the target.
        queue: as stackgen.Stream.
        decode_threads: threads that decode PNG images ahead (stackgen.Stream). None (default):
            one per core in the training process, less one for the augmentation when augmenting
            (at most 4); one in each DataLoader worker (the workers are the parallelism there).
        fault_drop: as stackgen.Stream.
        name: as stackgen.Stream.
        bus_key_file: the bus key, as for stackgen.Stream (default: this user's key; the
            recording is signed with it too).
        open_bus: no bus key, as for stackgen.Stream.
        rank: this process's rank under distributed training. None (default): from
            torch.distributed when it is initialised (DDP, torchrun), else the only process.
            Rank r of n with k DataLoader workers takes shards r * k .. r * k + k - 1 of n * k
            (seq % (n * k)), so no scene reaches two ranks and, reliable, none is missed;
            `count` is split between all shards. Every rank needs the same number of workers.
        world_size: the number of ranks; given with rank, or both None.
        transforms: a callable (image, target) -> (image, target) applied to every sample after
            stackgen's own augmentation (torchvision's detection references style), e.g. a
            normalisation or your own photometric changes; None (default): none.
        mix: real labelled images to mix into the stream: a folder (COCO with annotations.json,
            or labelme files: stackgen.coco.open_labelled_folder), or a dataset object with
            len(), image(i) (H, W, 3) uint8 RGB and target(i) -> (masks, class ids, iscrowd),
            such as stackgen.coco.CocoDataset or LabelmeDataset(folder, class_ids). None
            (default): none.
        mix_fraction: the share of real images among all samples, in [0, 1) (default 0.1 with
            `mix`). Sample n of a worker is real when floor((n + 1) f + p) > floor(n f + p), p
            drawn once from (seed, shard): over any N samples the count of real ones is within
            1 of N f. Each worker goes through the real images in an order of its own, drawn
            from (seed, shard, pass), and augments them as scenes (the same Augment,
            min_visib_fract, min_visible_px, grayscale and transforms), drawn from (seed, image
            index, use). A real sample's target has what a photo's labels give: visible masks,
            boxes, labels, iscrowd, area; the whole object counts as visible (visib_fract 1
            until augmentation cuts it), K and the poses are NaN, image_id is -(index + 1),
            scene is (-1, index, use). The stream's `count` counts scenes; the real samples
            come on top.

    Raises:
        stackgen.StreamError: as the stream does; also when the `record` file exists or cannot
            be created.
        ValueError: bad arguments.
    """

    def __init__(self, lcm_url: Optional[str] = None, *, reliable: bool = True, window: int = 8,
                 generator_ids: Optional[Sequence[int]] = None, timeout: Optional[float] = None,
                 count: int = 0, reuse: int = 1, reuse_buffer: int = 32, grayscale: bool = False,
                 augment: Union[None, bool, Augment] = None, min_visib_fract: float = 0.3,
                 min_visible_px: int = 16,
                 seed: int = 0, record: Optional[Union[str, os.PathLike]] = None,
                 replay: bool = False, depth: bool = False, queue: int = 16,
                 decode_threads: Optional[int] = None, fault_drop: float = 0.0,
                 name: Optional[str] = None, bus_key_file: Optional[str] = None,
                 open_bus: bool = False, rank: Optional[int] = None,
                 world_size: Optional[int] = None,
                 transforms: Optional[Callable[[torch.Tensor, Dict[str, torch.Tensor]],
                                               Tuple[Any, Any]]] = None,
                 mix: Union[None, str, os.PathLike, Any] = None,
                 mix_fraction: Optional[float] = None) -> None:
        super().__init__()
        mix, mix_fraction = _open_mix(mix, mix_fraction)
        if transforms is not None and not callable(transforms):
            raise ValueError("transforms must be a callable (image, target) -> (image, target), "
                             "got %r" % (transforms,))
        _rank_and_world(rank, world_size)  # arguments checked now
        if isinstance(reuse, bool) or not isinstance(reuse, int) or reuse < 1:
            raise ValueError("reuse must be a whole number >= 1, got %r" % (reuse,))
        if isinstance(reuse_buffer, bool) or not isinstance(reuse_buffer, int) or reuse_buffer < 1:
            raise ValueError("reuse_buffer must be a whole number >= 1, got %r" % (reuse_buffer,))
        if not isinstance(min_visib_fract, (int, float)) or not 0 <= min_visib_fract <= 1:
            raise ValueError("min_visib_fract must be in [0, 1], got %r" % (min_visib_fract,))
        if (isinstance(min_visible_px, bool) or not isinstance(min_visible_px, int) or
                min_visible_px < 1):
            raise ValueError("min_visible_px must be a whole number >= 1, got %r" %
                             (min_visible_px,))
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise ValueError("seed must be a whole number >= 0, got %r" % (seed,))
        if augment is True:
            augment = Augment()
        elif augment is False:
            augment = None
        if augment is not None and not callable(augment):
            raise ValueError("augment must be None, True, False or an Augment, got %r" % (augment,))
        url = stackgen.resolve_lcm_url(lcm_url or "")
        if replay:
            if not url.startswith("file://"):
                raise ValueError("replay reads a recorded log: lcm_url must be file://PATH, got %r"
                                 % (url,))
            if reuse != 1:
                raise ValueError("a replay repeats what the recording repeated: reuse must be 1")
        # a bad URL, no multicast route, a missing log or a log that is not one is refused here,
        # not later in each worker (a best-effort look that sends nothing)
        stackgen.Stream(url, reliable=False, count=1, status=False, bus_key_file=bus_key_file,
                        open_bus=open_bus).close()
        if record is not None:
            record = _create_record(os.fspath(record))
        self.lcm_url = url
        self.reliable = reliable
        self.window = window
        self.generator_ids = generator_ids
        self.timeout = timeout
        self.count = count
        self.reuse = reuse
        self.reuse_buffer = reuse_buffer
        self.grayscale = grayscale
        self.augment = augment
        self.min_visib_fract = float(min_visib_fract)
        self.min_visible_px = min_visible_px
        self.seed = seed
        self.record = record
        self.replay = bool(replay)
        self.depth = bool(depth)
        self.queue = queue
        self.decode_threads = decode_threads
        self.fault_drop = fault_drop
        self.name = name
        self.bus_key_file = bus_key_file
        self.open_bus = bool(open_bus)
        self.rank = rank
        self.world_size = world_size
        self.transforms = transforms
        self.mix = mix
        self.mix_fraction = float(mix_fraction) if mix is not None else 0.0

    def _open(self, worker, workers):
        if workers > MAX_WORKERS:
            raise stackgen.StreamError(
                "a stream splits between at most %d shards (ranks x DataLoader workers), not %d" %
                (MAX_WORKERS, workers))
        count = 0
        if self.count > 0:
            count = self.count // workers + (1 if worker < self.count % workers else 0)
            if count == 0:
                return None
        name = self.name
        if name and workers > 1:
            name = "%s/shard%dof%d" % (name, worker, workers)
        return stackgen.Stream(
            self.lcm_url, reliable=self.reliable, window=self.window,
            generator_ids=self.generator_ids, timeout=self.timeout, count=count,
            shard=(worker, workers), queue=self.queue, depth=self.depth, repeats=self.replay,
            # only augmentation reads the instance map; the masks come from the RLE otherwise
            instance_map=self.augment is not None, decode_threads=self._decode_threads(workers),
            fault_drop=self.fault_drop, name=name, bus_key_file=self.bus_key_file,
            open_bus=self.open_bus)

    def _decode_threads(self, workers):
        if self.decode_threads is not None:
            return self.decode_threads
        if get_worker_info() is not None:
            return 1
        cores = os.cpu_count() or 1
        return max(1, min(4, cores - (1 if self.augment is not None else 0)))

    def __iter__(self):
        """Takes this worker's shard of the stream.

        Yields:
            (image, target) pairs, as the class describes them.
        """
        info = get_worker_info()
        worker, workers = (info.id, info.num_workers) if info is not None else (0, 1)
        if info is not None:
            # one core per worker: no thread pools fighting over it
            cv2.setNumThreads(1)
        # this rank's workers take shards rank * workers + worker of world * workers (one rank:
        # the shard is the worker, as before)
        rank, world = _rank_and_world(self.rank, self.world_size)
        if self.record and world > 1:
            raise stackgen.StreamError("record: one file cannot take the samples of %d ranks; "
                                       "record with one process" % world)
        worker, workers = rank * workers + worker, world * workers
        stream = self._open(worker, workers)
        if stream is None:
            return

        recorder = stackgen.LogRecorder(self.record, bus_key_file=self.bus_key_file,
                                        open_bus=self.open_bus) if self.record else None
        picker = np.random.default_rng([self.seed, worker, 0x5EED])
        mixer = _RealMixer(self, worker) if self.mix_fraction > 0 else None
        buffer = []  # [scene, uses] of recent scenes, oldest first
        ended = False
        try:
            while True:
                while mixer is not None and mixer.next_is_real():
                    yield self._finish(*mixer.sample())
                fresh = None
                if not ended:
                    reusable = self.reuse > 1 and any(uses < self.reuse for _, uses in buffer)
                    if reusable:
                        try:
                            fresh = stream.next(0.0)
                        except stackgen.StreamTimeout:
                            fresh = False  # nothing new right now
                    else:
                        fresh = stream.next(self.timeout)
                    if fresh is None:
                        ended = True
                if fresh:
                    scene, use = fresh, (fresh.occurrence if self.replay else 0)
                    if self.reuse > 1:
                        buffer.append([scene, 1])
                        if len(buffer) > self.reuse_buffer:
                            buffer.pop(0)
                elif ended:
                    break
                else:
                    eligible = [entry for entry in buffer if entry[1] < self.reuse]
                    entry = eligible[int(picker.integers(len(eligible)))]
                    scene, use = entry[0], entry[1]
                    entry[1] += 1
                if recorder is not None:
                    recorder.append(scene)
                if mixer is not None:
                    mixer.count_synthetic()
                yield self._finish(*self.sample(scene, use))
        finally:
            stream.close()

    def _finish(self, image, target):
        if self.transforms is not None:
            image, target = self.transforms(image, target)
        return image, target

    def _scene_labels(self, scene, candidates):
        # not augmented: the scene's own labels, the masks decoded from its RLE (as exact_labels
        # would compute them from the instance map, only faster)
        keep = np.flatnonzero(scene.px_count_visib[candidates] > 0)
        chosen = candidates[keep]
        x, y, w, h = scene.bbox_visib[chosen].T.astype(np.float32)
        visib = scene.visib_fract[chosen]
        good = (scene.annotated[chosen] & (visib >= self.min_visib_fract) &
                (scene.px_count_visib[chosen] >= max(1, self.min_visible_px)))
        return {
            "keep": keep,
            "masks": scene.masks_visib(chosen.tolist()),
            "boxes": np.stack([x, y, x + w, y + h], axis=1).reshape(-1, 4),
            "px_count_visib": scene.px_count_visib[chosen].astype(np.int64),
            "px_count_all": scene.px_count_all[chosen].astype(np.int64),
            "visib_fract": visib,
            "iscrowd": (~good).astype(np.int64),
        }

    def sample(self, scene: stackgen.Scene, use: int = 0
               ) -> Tuple[torch.Tensor, Dict[str, torch.Tensor]]:
        """The (image, target) pair of a scene for one use.

        Augmented with the draws of (seed, generator_id, seq, use, scene seed).

        Args:
            scene: the scene.
            use: its use number (default 0).

        Returns:
            The (image, target) pair, as the class describes it.
        """
        rng = np.random.default_rng(
            [self.seed, scene.generator_id, scene.seq, use, scene.seed & _SEED_MASK])
        annotated = scene.annotated
        ignored = scene.ignored
        candidates = np.flatnonzero(annotated | ignored)
        image = scene.color
        if image.ndim == 2:
            image = image[:, :, None]
        if self.grayscale and image.shape[2] == 3:
            image = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)[:, :, None]
        sample = {
            "image": image,
            "instance_map": scene.instance_map,
            "depth": scene.depth if self.depth else None,
            "K": scene.K,
            "instance_ids": scene.instance_ids[candidates],
            "px_count_all": scene.px_count_all[candidates],
            "annotated": annotated[candidates],
            "ignored": ignored[candidates],
            "bbox_obj": scene.bbox_obj[candidates],
            "bbox_visib": scene.bbox_visib[candidates],
            "boxed_masks_obj": lambda: scene.boxed_masks_obj(candidates.tolist()),
        }
        if self.augment is not None:
            sample = self.augment(sample, rng)
            labels = exact_labels(sample["instance_map"], sample["instance_ids"],
                                  sample["px_count_all"], sample["annotated"], sample["ignored"],
                                  self.min_visib_fract, sample["regions"], self.min_visible_px)
        else:
            labels = self._scene_labels(scene, candidates)
        chosen = candidates[labels["keep"]]
        depth = None
        if self.depth:
            depth = sample["depth"].astype(np.float32) * np.float32(scene.depth_scale_mm)
        return self._pack(sample["image"], labels, scene.class_ids[chosen],
                          scene.instance_ids[chosen], scene.camera_from_object[chosen],
                          scene.world_from_object[chosen], sample["K"],
                          scene.generator_id * 100000000 + scene.seq + 1,
                          (scene.generator_id, scene.seq, use), depth)

    def sample_real(self, index: int, use: int = 0
                    ) -> Tuple[torch.Tensor, Dict[str, torch.Tensor]]:
        """The (image, target) pair of a real image of `mix` for one use.

        Augmented with the draws of (seed, index, use).

        Args:
            index: the image's index in `mix`.
            use: its use number (default 0).

        Returns:
            The (image, target) pair; see `mix` for its target.
        """
        rng = np.random.default_rng([self.seed, _REAL_TAG, index, use])
        image = self.mix.image(index)
        masks, class_ids, iscrowd = self.mix.target(index)
        height, width = image.shape[:2]
        if self.grayscale:
            image = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)[:, :, None]
        count = len(masks)
        # the masks as an instance map (a pixel two masks claim goes to the later one), so
        # that augmentation and labels work as for a scene
        instance_map = np.zeros((height, width), dtype=np.uint16)
        for k in range(count):
            instance_map[np.asarray(masks[k]) > 0] = k + 1
        instance_ids = np.arange(1, count + 1, dtype=np.uint16)
        boxes = np.zeros((count, 4), dtype=np.int32)
        px_count = np.zeros(count, dtype=np.int64)
        for k in range(count):
            mask = np.equal(instance_map, k + 1).view(np.uint8)
            px_count[k] = cv2.countNonZero(mask)
            if px_count[k]:
                boxes[k] = cv2.boundingRect(mask)
        iscrowd = np.asarray(iscrowd, dtype=bool)
        sample = {
            "image": image,
            "instance_map": instance_map,
            "depth": None,
            "K": np.full((3, 3), np.nan),
            "instance_ids": instance_ids,
            "px_count_all": px_count,  # a photo's labels are what is visible: all of it
            "annotated": ~iscrowd,
            "ignored": iscrowd,
            "bbox_obj": boxes,
            "bbox_visib": boxes,
            "boxed_masks_obj": lambda: [
                np.equal(instance_map[y:y + h, x:x + w], k + 1).view(np.uint8)
                for k, (x, y, w, h) in enumerate(boxes)],
        }
        if self.augment is not None:
            sample = self.augment(sample, rng)
            regions = sample["regions"]
        else:
            regions = np.array([(x, y, x + w, y + h) for x, y, w, h in boxes],
                               dtype=np.int64).reshape(-1, 4)
        labels = exact_labels(sample["instance_map"], instance_ids, sample["px_count_all"],
                              ~iscrowd, iscrowd, self.min_visib_fract, regions,
                              self.min_visible_px)
        keep = labels["keep"]
        unknown = np.full((len(keep), 4, 4), np.nan)
        depth = np.zeros((height, width), dtype=np.float32) if self.depth else None
        return self._pack(sample["image"], labels, np.asarray(class_ids)[keep],
                          instance_ids[keep], unknown, unknown.copy(), sample["K"], -(index + 1),
                          (-1, index, use), depth)

    def _pack(self, image, labels, class_ids, instance_ids, camera_from_object,
              world_from_object, K, image_id, scene, depth_mm):
        """The (image, target) pair in torch tensors."""
        # (C, H, W) float32 in [0, 1], in one pass (a new array: the scene's image stays as is)
        image = torch.from_numpy(
            np.ascontiguousarray(image.transpose(2, 0, 1), dtype=np.float32))
        image.div_(255.0)
        if not self.grayscale and image.shape[0] == 1:
            image = image.expand(3, -1, -1).contiguous()
        target = {
            "boxes": torch.from_numpy(labels["boxes"]),
            "labels": torch.from_numpy(np.asarray(class_ids).astype(np.int64)),
            "masks": torch.from_numpy(labels["masks"]),
            "iscrowd": torch.from_numpy(labels["iscrowd"]),
            "area": torch.from_numpy(labels["px_count_visib"].astype(np.float32)),
            "visib_fract": torch.from_numpy(labels["visib_fract"].astype(np.float32)),
            "px_count_all": torch.from_numpy(labels["px_count_all"]),
            "px_count_visib": torch.from_numpy(labels["px_count_visib"]),
            "instance_ids": torch.from_numpy(np.asarray(instance_ids).astype(np.int64)),
            "camera_from_object": torch.from_numpy(camera_from_object),
            "world_from_object": torch.from_numpy(world_from_object),
            "K": torch.from_numpy(np.asarray(K, dtype=np.float64)),
            "image_id": torch.tensor(image_id, dtype=torch.int64),
            "scene": torch.tensor(scene, dtype=torch.int64),
        }
        if depth_mm is not None:
            target["depth_mm"] = torch.from_numpy(depth_mm)
        return image, target


class _RealMixer:
    """Where a worker's real samples go and which real image each is (StreamDataset's mix)."""

    def __init__(self, dataset, shard):
        self.dataset = dataset
        self.fraction = dataset.mix_fraction
        self.shard = shard
        self.phase = float(np.random.default_rng([dataset.seed, shard, _REAL_TAG]).random())
        self.position = 0  # samples handed out, real and synthetic
        self.order = []
        self.passes = 0
        self.uses = {}

    def _slot_is_real(self, n):
        return (math.floor((n + 1) * self.fraction + self.phase) >
                math.floor(n * self.fraction + self.phase))

    def next_is_real(self):
        return self._slot_is_real(self.position)

    def count_synthetic(self):
        self.position += 1

    def sample(self):
        if not self.order:
            rng = np.random.default_rng([self.dataset.seed, self.shard, _REAL_TAG, self.passes])
            self.order = list(rng.permutation(len(self.dataset.mix)))
            self.passes += 1
        index = int(self.order.pop(0))
        use = self.uses.get(index, 0)
        self.uses[index] = use + 1
        self.position += 1
        return self.dataset.sample_real(index, use)
