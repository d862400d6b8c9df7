"""A stackgen-coco dataset's webdataset shards streamed into a training loop, on any host that can
read them: the shards of `stackgen-coco --shards N` (or `stackgen-merge --shards N` after a
cluster job) on a shared file system, or through any command that prints a shard (webdataset's
"pipe:" form: `pipe:aws s3 cp s3://bucket/shard-000000.tar -`), with no bus and no random access.

    from torch.utils.data import DataLoader
    import stackgen.torch as sgt
    from stackgen.shards import ShardDataset

    dataset = ShardDataset("/shared/run1/merged")      # its shards/shard-*.tar, in order
    loader = DataLoader(dataset, batch_size=2, num_workers=2, collate_fn=sgt.collate)
    for images, targets in loader:
        losses = model(list(images), [sgt.without_ignore_regions(t) for t in targets])

Each DataLoader worker of each rank (torch.distributed, as StreamDataset) reads its own shards
(shard i goes to unit i % (ranks x workers)), so no image reaches two of them; a sample's
target has what StreamDataset's has for the same scene without augmentation.
"""

from __future__ import annotations

import glob
import json
import os
import subprocess
import tarfile
from typing import Any, Callable, Dict, Iterator, List, Optional, Sequence, Tuple, Union

import cv2
import numpy as np
import torch
from torch.utils.data import IterableDataset, get_worker_info

from stackgen.coco import decode_segmentation
from stackgen.torch import _rank_and_world

__all__ = ["ShardDataset", "read_shard", "shard_sources"]

_IMAGE_SUFFIXES = (".png", ".jpg")


def shard_sources(shards: Union[str, os.PathLike, Sequence[Union[str, os.PathLike]]]
                  ) -> List[str]:
    """The shards to read, in order.

    Args:
        shards: a dataset folder (its shards/shard-*.tar), a .tar file, "pipe:COMMAND", or a
            list of these.

    Returns:
        The .tar paths and pipe: commands.

    Raises:
        ValueError: a folder without shards, or a path that is neither a folder nor a .tar.
    """
    if isinstance(shards, (str, os.PathLike)):
        shards = [shards]
    sources = []
    for shard in shards:
        shard = os.fspath(shard)
        if shard.startswith("pipe:") or (shard.endswith(".tar") and os.path.isfile(shard)):
            sources.append(shard)
        elif os.path.isdir(shard):
            found = sorted(glob.glob(os.path.join(shard, "shards", "shard-*.tar")))
            if not found:
                raise ValueError("%s: no webdataset shards (shards/shard-*.tar): write them "
                                 "with stackgen-coco --shards N or stackgen-merge --shards N"
                                 % shard)
            sources.extend(found)
        else:
            raise ValueError("%s: not a dataset folder, a .tar shard or pipe:COMMAND" % shard)
    return sources


def _open(source):
    """A readable stream of the shard, and what to close after it."""
    if source.startswith("pipe:"):
        process = subprocess.Popen(source[len("pipe:"):], shell=True, stdout=subprocess.PIPE)
        return process.stdout, process
    return open(source, "rb"), None


def read_shard(source: str) -> Iterator[Tuple[str, np.ndarray, Dict[str, Any]]]:
    """The images of one shard, in the shard's order, read as a stream.

    Args:
        source: a .tar path or "pipe:COMMAND".

    Yields:
        (key, image, records): the image's key (<generator_id>_<seq:06>), its (H, W, 3) uint8
        RGB pixels, and its records of annotations.json ({"image": {...}, "annotations": [...]}).

    Raises:
        ValueError: the shard is not a tar, ends early, or holds a key without its image or
            records (the message names the shard and the key).
    """
    stream, process = _open(source)
    whole = False
    try:
        key, image, records = None, None, None
        with tarfile.open(fileobj=stream, mode="r|") as tar:
            for member in tar:
                name = os.path.basename(member.name)
                member_key, _, suffix = name.partition(".")
                if member_key != key:
                    if key is not None:
                        yield _whole(source, key, image, records)
                    key, image, records = member_key, None, None
                data = tar.extractfile(member).read() if member.isfile() else b""
                if "." + suffix in _IMAGE_SUFFIXES:
                    bgr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
                    if bgr is None:
                        raise ValueError("%s: %s: the image does not decode" % (source, name))
                    image = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
                elif suffix == "json":
                    records = json.loads(data)
        whole = True
        if key is not None:
            yield _whole(source, key, image, records)
    except (tarfile.TarError, EOFError) as error:
        if process is not None and process.wait() != 0:
            whole = True  # said below: the command's failure is the cause
        else:
            raise ValueError("%s: not a whole tar shard (%s)" % (source, error)) from None
    finally:
        stream.close()
        if process is not None:
            process.wait()
            # (a reader that stopped early closed the pipe: the command's failure is its own)
            if whole and process.returncode != 0:
                raise ValueError("%s: the command exited with %d" % (source, process.returncode))


def _whole(source, key, image, records):
    if image is None or records is None:
        raise ValueError("%s: %s has no %s" % (source, key, "image" if image is None else
                                                "records (.json)"))
    return key, image, records


class ShardDataset(IterableDataset):
    """(image, target) pairs from stackgen-coco's webdataset shards, for torchvision detection
    models, as StreamDataset gives them for a scene without augmentation.

    target (torch tensors; M instances: the annotations of the image, ignore regions included):
        boxes (M, 4) float32 XYXY of the visible pixels; labels (M,) int64 category ids; masks
        (M, H, W) uint8 visible masks; iscrowd (M,) int64 (1: an ignore region); area (M,)
        float32 visible pixels; visib_fract (M,) float32; px_count_all, px_count_visib,
        instance_ids (M,) int64; camera_from_object, world_from_object (M, 4, 4) float64 (mm;
        NaN where a record has no pose); K (3, 3) float64;
        image_id () int64 (the COCO image id); scene (3,) int64 (generator id, seq, 0).

    Args:
        shards: a dataset folder, .tar paths or pipe: commands (see shard_sources).
        rank: this process's rank, and world_size the ranks (default: torch.distributed's when
            it is initialised, else 0 of 1).
        world_size: see rank.
        transforms: a callable (image, target) -> (image, target) applied to every sample.
        loop: read the shards again and again (an epoch never ends) instead of once.

    Raises:
        ValueError: see shard_sources; rank without world_size.
    """

    def __init__(self, shards: Union[str, os.PathLike, Sequence[Union[str, os.PathLike]]], *,
                 rank: Optional[int] = None, world_size: Optional[int] = None,
                 transforms: Optional[Callable[[torch.Tensor, Dict[str, torch.Tensor]],
                                               Tuple[torch.Tensor, Dict[str, torch.Tensor]]]]
                 = None,
                 loop: bool = False) -> None:
        super().__init__()
        self.sources = shard_sources(shards)
        self.rank, self.world_size = _rank_and_world(rank, world_size)
        self.transforms = transforms
        self.loop = loop

    def __iter__(self):
        info = get_worker_info()
        workers, worker = (info.num_workers, info.id) if info is not None else (1, 0)
        units = self.world_size * workers
        unit = self.rank * workers + worker
        mine = [source for k, source in enumerate(self.sources) if k % units == unit]
        while True:
            for source in mine:
                for _, image, records in read_shard(source):
                    image, target = self.sample(image, records)
                    if self.transforms is not None:
                        image, target = self.transforms(image, target)
                    yield image, target
            if not self.loop or not mine:
                return

    @staticmethod
    def sample(image: np.ndarray, records: Dict[str, Any]
               ) -> Tuple[torch.Tensor, Dict[str, torch.Tensor]]:
        """The (image, target) pair of one image of a shard (read_shard's image and records)."""
        height, width = image.shape[:2]
        annotations = records["annotations"]
        count = len(annotations)
        masks = np.zeros((count, height, width), dtype=np.uint8)
        boxes = np.zeros((count, 4), dtype=np.float32)
        poses = {"camera_from_object": ("cam_R_m2c", "cam_t_m2c"),
                 "world_from_object": ("world_R_m2w", "world_t_m2w")}
        pose = {name: np.full((count, 4, 4), np.nan) for name in poses}
        for k, annotation in enumerate(annotations):
            masks[k] = decode_segmentation(annotation["segmentation"], height, width)
            x, y, w, h = annotation["bbox"]
            boxes[k] = (x, y, x + w, y + h)
            for name, (rotation, translation) in poses.items():
                if rotation in annotation:
                    pose[name][k] = np.eye(4)
                    pose[name][k, :3, :3] = np.reshape(annotation[rotation], (3, 3))
                    pose[name][k, :3, 3] = annotation[translation]

        def column(name, dtype, default=0):
            return torch.tensor([a.get(name, default) for a in annotations], dtype=dtype)

        info = records["image"]
        camera = info.get("stackgen", {}).get("camera", {})
        K = np.full((3, 3), np.nan)
        if camera:
            K = np.array([[camera["fx"], 0, camera["cx"]], [0, camera["fy"], camera["cy"]],
                          [0, 0, 1]], dtype=np.float64)
        stackgen_ids = info.get("stackgen", {})
        pixels = torch.from_numpy(np.ascontiguousarray(image.transpose(2, 0, 1),
                                                       dtype=np.float32)).div_(255.0)
        target = {
            "boxes": torch.from_numpy(boxes),
            "labels": column("category_id", torch.int64, 1),
            "masks": torch.from_numpy(masks),
            "iscrowd": column("iscrowd", torch.int64),
            "area": column("area", torch.float32),
            "visib_fract": column("visib_fract", torch.float32, 1.0),
            "px_count_all": column("px_count_all", torch.int64),
            "px_count_visib": column("px_count_visib", torch.int64),
            "instance_ids": column("instance_id", torch.int64),
            "camera_from_object": torch.from_numpy(pose["camera_from_object"]),
            "world_from_object": torch.from_numpy(pose["world_from_object"]),
            "K": torch.from_numpy(K),
            "image_id": torch.tensor(info["id"], dtype=torch.int64),
            "scene": torch.tensor([stackgen_ids.get("generator_id", -1),
                                   stackgen_ids.get("seq", -1), 0], dtype=torch.int64),
        }
        return pixels, target
