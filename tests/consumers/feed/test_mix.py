"""Real labelled images mixed into the stream (StreamDataset's mix and mix_fraction): the share
over 192 samples, the labels a real sample carries, the same draws for the same seed, and the
readers of the folders (COCO and labelme)."""

import json

import cv2
import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

import stackgen
import stackgen.torch as sgt
from stackgen.coco import CocoDataset, LabelmeDataset, open_labelled_folder
from conftest import TINY_LOG, coco_of_fixture_log


@pytest.fixture(scope="module")
def photos(tmp_path_factory):
    """A COCO folder standing for labelled photos: stackgen-coco's dataset of the fixture log."""
    return coco_of_fixture_log(tmp_path_factory.mktemp("photos") / "coco")


@pytest.fixture(scope="module")
def long_log(tmp_path_factory):
    """A log to replay as 144 samples: the fixture's 4 scenes, each recorded 36 times."""
    path = str(tmp_path_factory.mktemp("log") / "long.lcmlog")
    scenes = list(stackgen.Stream("file://" + TINY_LOG, open_bus=True))
    recorder = stackgen.LogRecorder(path)
    for _ in range(36):
        for scene in scenes:
            recorder.append(scene)
    del recorder
    return path


def samples(long_log, photos, seed, workers=2, fraction=0.25):
    dataset = sgt.StreamDataset("file://" + long_log, replay=True, augment=True, seed=seed,
                                mix=photos, mix_fraction=fraction)
    loader = DataLoader(dataset, batch_size=4, num_workers=workers, collate_fn=sgt.collate)
    # copies: a worker's tensors arrive as shared memory, one file descriptor each
    return [(image.clone(), {key: value.clone() for key, value in target.items()})
            for images, targets in loader for image, target in zip(images, targets)]


# a quarter of 192 samples are real, in both workers; each real one carries its photo's
# labels, augmented; every photo is used, evenly; the same seed gives the same samples
def test_mix_fraction_and_draws(long_log, photos):
    got = samples(long_log, photos, seed=3)
    real = [(image, target) for image, target in got if int(target["scene"][0]) == -1]
    synthetic = len(got) - len(real)
    assert synthetic == 144
    assert abs(len(real) / len(got) - 0.25) <= 0.02
    assert abs(len(real) - 0.25 * len(got)) <= 2  # within one per worker
    folder = CocoDataset(photos)
    categories = set(folder.categories)
    uses = np.bincount([int(t["scene"][1]) for _, t in real], minlength=len(folder))
    assert uses.max() - uses.min() <= 2
    moved = 0
    for image, target in real:
        index = int(target["scene"][1])
        assert int(target["image_id"]) == -(index + 1)
        assert set(target["labels"].tolist()) <= categories
        assert torch.isnan(target["K"]).all() and torch.isnan(target["camera_from_object"]).all()
        assert image.shape == (3, folder.images[index]["height"], folder.images[index]["width"])
        for box, mask in zip(target["boxes"].tolist(), target["masks"]):
            ys, xs = np.nonzero(mask.numpy())
            assert box == [xs.min(), ys.min(), xs.max() + 1, ys.max() + 1]
        masks, _, _ = folder.target(index)
        if target["masks"].shape[0] != len(masks) or not np.array_equal(
                target["masks"].numpy().sum(axis=0) > 0, masks.sum(axis=0) > 0):
            moved += 1
    assert moved > len(real) // 2  # augmented as scenes are
    again = samples(long_log, photos, seed=3)
    assert [t["scene"].tolist() for _, t in again] == [t["scene"].tolist() for _, t in got]
    assert all(torch.equal(a[0], b[0]) for a, b in zip(again, got))
    other = samples(long_log, photos, seed=4)
    assert [t["scene"].tolist() for _, t in other] != [t["scene"].tolist() for _, t in got]


# not augmented, a real sample is its photo: the image, and each instance's mask, box and class
def test_real_sample_is_the_photo(photos):
    dataset = sgt.StreamDataset("file://" + TINY_LOG, open_bus=True, mix=photos)
    assert dataset.mix_fraction == 0.1
    folder = CocoDataset(photos)
    for index in range(len(folder)):
        image, target = dataset.sample_real(index)
        assert np.array_equal((image.numpy().transpose(1, 2, 0) * 255).round().astype(np.uint8),
                              folder.image(index))
        masks, labels, iscrowd = folder.target(index)
        keep = masks.reshape(len(masks), -1).any(axis=1)
        assert np.array_equal(target["masks"].numpy(), masks[keep])
        assert target["labels"].tolist() == labels[keep].tolist()
        assert target["iscrowd"].tolist() == iscrowd[keep].astype(int).tolist()
        assert torch.all(target["visib_fract"] == 1)


def write_labelme(folder, name, shapes, image):
    cv2.imwrite(str(folder / (name + ".png")), image)
    (folder / (name + ".json")).write_text(json.dumps({
        "version": "5.2.1", "flags": {}, "shapes": shapes, "imagePath": name + ".png",
        "imageData": None, "imageHeight": image.shape[0], "imageWidth": image.shape[1]}))


def shape(label, points, kind="polygon", group=None):
    return {"label": label, "points": points, "group_id": group, "shape_type": kind,
            "flags": {}}


# labelme files: polygons and rectangles become masks, a label with a group_id one instance,
# labels class ids; what cannot be read is refused, naming the file and the shape
def test_labelme_folder(tmp_path):
    image = np.full((40, 60, 3), 90, dtype=np.uint8)
    write_labelme(tmp_path, "a", [
        shape("part", [[2, 2], [12, 2], [12, 8], [2, 8]]),
        shape("part", [[20, 20], [29, 29]], "rectangle", group=1),
        shape("part", [[40, 20], [49, 29]], "rectangle", group=1),
    ], image)
    folder = open_labelled_folder(str(tmp_path))
    assert isinstance(folder, LabelmeDataset) and len(folder) == 1
    masks, labels, iscrowd = folder.target(0)
    assert masks.shape == (2, 40, 60) and labels.tolist() == [1, 1] and not iscrowd.any()
    assert masks[0].sum() == 11 * 7 and masks[0][2:9, 2:13].all()
    assert masks[1].sum() == 2 * 10 * 10 and masks[1][20:30, 40:50].all()
    assert np.array_equal(folder.image(0), image)

    write_labelme(tmp_path, "b", [shape("bolt", [[1, 1], [5, 1], [5, 5]])], image)
    with pytest.raises(ValueError, match=r"labels \['bolt', 'part'\]: give class_ids"):
        LabelmeDataset(str(tmp_path))
    both = LabelmeDataset(str(tmp_path), class_ids={"part": 1, "bolt": 2})
    assert both.target(1)[1].tolist() == [2]
    write_labelme(tmp_path, "c", [shape("part", [[1, 1], [3, 3]], "circle")], image)
    with pytest.raises(ValueError, match=r"c\.json: shape 0 \(part\): a circle"):
        LabelmeDataset(str(tmp_path), class_ids={"part": 1, "bolt": 2})
    # a shape without a label; an imagePath written on Windows
    (tmp_path / "c.json").unlink()
    other = tmp_path / "other"
    (other / "pics").mkdir(parents=True)
    cv2.imwrite(str(other / "pics" / "d.png"), image)
    (other / "d.json").write_text(json.dumps({
        "shapes": [shape("part", [[1, 1], [9, 1], [9, 9]])], "imagePath": "pics\\d.png",
        "imageHeight": 40, "imageWidth": 60}))
    assert np.array_equal(LabelmeDataset(str(other)).image(0), image)
    (other / "d.json").write_text(json.dumps({
        "shapes": [{"points": [[1, 1], [9, 1], [9, 9]]}], "imagePath": "pics/d.png",
        "imageHeight": 40, "imageWidth": 60}))
    with pytest.raises(ValueError, match=r"d\.json: shape 0 has no label"):
        LabelmeDataset(str(other))
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="empty: neither a COCO folder"):
        open_labelled_folder(str(tmp_path / "empty"))


def test_bad_mix_arguments(photos):
    url = "file://" + TINY_LOG
    with pytest.raises(ValueError, match="mix_fraction needs mix"):
        sgt.StreamDataset(url, open_bus=True, mix_fraction=0.2)
    with pytest.raises(ValueError, match=r"mix_fraction must be in \[0, 1\), got 1"):
        sgt.StreamDataset(url, open_bus=True, mix=photos, mix_fraction=1)
    with pytest.raises(ValueError, match="no such folder"):
        sgt.StreamDataset(url, open_bus=True, mix=photos + "-missing")
