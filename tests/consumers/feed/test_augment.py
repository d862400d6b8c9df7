"""Training-time augmentation with exact labels, and reproducible batches, on the recorded scenes
of tests/fixtures/logs/tiny.lcmlog (4 scenes, 6 connectors each, annotated and ignored ones)."""

import cv2
import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

import stackgen
import stackgen.torch as sgt
from conftest import TINY_LOG

URL = "file://" + TINY_LOG
# the fixture log was recorded on an open bus (no key): it is read with open_bus=True
OPEN = dict(open_bus=True)
# every geometric lever on, with large ranges, and the photometric ones
EVERYTHING = dict(hflip=0.5, vflip=0.5, crop=0.7, crop_scale=(0.4, 1.0), zoom=0.7,
                  zoom_range=(0.6, 1.6), affine=0.7, rotate_deg=40, shear_deg=10, translate=0.2,
                  erase=0.7, brightness=0.3, contrast=0.3)
NOTHING = dict(hflip=0, vflip=0, crop=0, zoom=0, affine=0, erase=0, brightness=0, contrast=0)


def scenes():
    return list(stackgen.Stream(URL, **OPEN))


def samples(augment, seeds=range(6), min_visib_fract=0.3):
    """(scene, target) for every scene of the log and seed."""
    result = []
    for seed in seeds:
        dataset = sgt.StreamDataset(URL, augment=augment, seed=seed,
                                    min_visib_fract=min_visib_fract, **OPEN)
        for scene in scenes():
            result.append((scene, dataset.sample(scene)[1]))
    return result


def mask_box(mask):
    x, y, w, h = cv2.boundingRect(mask)
    return [x, y, x + w, y + h]


# whatever the augmentation, every box is the box of its (transformed) visible mask, every mask
# has pixels, area counts them, visib_fract is area / px_count_all, and the iscrowd rule holds
def test_box_is_the_box_of_its_transformed_mask():
    checked = 0
    for scene, target in samples(sgt.Augment(**EVERYTHING), seeds=range(10)):
        for row in range(len(target["boxes"])):
            mask = target["masks"][row].numpy()
            assert mask.any()
            assert target["boxes"][row].tolist() == mask_box(mask)
            assert target["area"][row] == mask.sum() == target["px_count_visib"][row]
            assert target["visib_fract"][row] == pytest.approx(
                float(target["area"][row]) / float(target["px_count_all"][row]), rel=1e-6)
            k = int(np.flatnonzero(scene.instance_ids == int(target["instance_ids"][row]))[0])
            annotated = scene.annotated[k] and target["visib_fract"][row] >= 0.3
            assert target["iscrowd"][row] == (0 if annotated else 1)
            checked += 1
    assert checked > 100


# flips move pixels without resampling: the labels are the scene's, mirrored, exactly, and the
# full mask keeps its size; K becomes A @ K
def test_flips_mirror_the_labels_exactly():
    for scene, target in samples(sgt.Augment(**dict(NOTHING, hflip=1.0, vflip=1.0)), seeds=[0]):
        masks = scene.masks_visib()
        for row, instance_id in enumerate(target["instance_ids"].tolist()):
            k = int(np.flatnonzero(scene.instance_ids == instance_id)[0])
            assert np.array_equal(target["masks"][row].numpy(), masks[k][::-1, ::-1])
            assert target["px_count_all"][row] == scene.px_count_all[k]
            assert target["visib_fract"][row] == np.float32(scene.visib_fract[k])
        flip = np.array([[-1, 0, scene.width - 1], [0, -1, scene.height - 1], [0, 0, 1.0]])
        assert np.allclose(target["K"].numpy(), flip @ scene.K)


# an erased rectangle hides what lies under it: no visible fraction rises, some fall, the full
# size of every object stays
def test_erasure_lowers_visib_fract():
    lowered = 0
    for scene, target in samples(sgt.Augment(**dict(NOTHING, erase=1.0, erase_area=(0.1, 0.3))),
                                 seeds=range(8)):
        for row, instance_id in enumerate(target["instance_ids"].tolist()):
            k = int(np.flatnonzero(scene.instance_ids == instance_id)[0])
            assert target["px_count_all"][row] == scene.px_count_all[k]
            assert target["visib_fract"][row] <= np.float32(scene.visib_fract[k])
            lowered += int(target["visib_fract"][row] < np.float32(scene.visib_fract[k]))
    assert lowered > 0


# a crop cuts objects at the image border: an annotated object left less than min_visib_fract
# visible becomes an ignore region (iscrowd 1), not a label of a sliver; one cut away entirely
# is gone; the full size counts the part outside the image
def test_crop_out_instances_become_ignore_regions():
    became_ignore = 0
    for scene, target in samples(sgt.Augment(**dict(NOTHING, crop=1.0, crop_scale=(0.5, 0.5))),
                                 seeds=range(12)):
        rows = {int(i): r for r, i in enumerate(target["instance_ids"].tolist())}
        for k, instance_id in enumerate(scene.instance_ids.tolist()):
            if not scene.annotated[k]:
                continue
            if instance_id not in rows:
                continue  # cut away entirely
            row = rows[instance_id]
            # a 2x zoom: the full mask is about four times as large, in or out of the image
            assert target["px_count_all"][row] == pytest.approx(4 * scene.px_count_all[k],
                                                                rel=0.15)
            if target["visib_fract"][row] < 0.3:
                assert target["iscrowd"][row] == 1
                became_ignore += 1
            else:
                assert target["iscrowd"][row] == 0
    assert became_ignore > 0


# without augmentation the target holds the scene's labels: boxes, masks and fractions as the
# generator computed them; iscrowd 1 exactly where the generator kept an ignore region
def test_no_augmentation_keeps_the_scene_labels():
    for scene, target in samples(None, seeds=[0]):
        candidates = np.flatnonzero(scene.annotated | scene.ignored)
        assert target["instance_ids"].tolist() == scene.instance_ids[candidates].tolist()
        for row, k in enumerate(candidates):
            x, y, w, h = scene.bbox_visib[k]
            assert target["boxes"][row].tolist() == [x, y, x + w, y + h]
            assert target["iscrowd"][row] == int(scene.ignored[k])
            assert target["visib_fract"][row] == np.float32(scene.visib_fract[k])
        assert np.array_equal(target["K"].numpy(), scene.K)


# the same log and seed give the same batches, through two DataLoader workers as well; another
# seed gives other ones
def test_same_log_and_seed_give_identical_batches():
    def batches(seed, workers):
        dataset = sgt.StreamDataset(URL, augment=sgt.Augment(**EVERYTHING), seed=seed, **OPEN)
        loader = DataLoader(dataset, batch_size=2, num_workers=workers, collate_fn=sgt.collate)
        return [(torch.stack(images), [t["boxes"] for t in targets],
                 [t["masks"] for t in targets]) for images, targets in loader]

    def same(a, b):
        return len(a) == len(b) and all(
            torch.equal(x[0], y[0]) and all(map(torch.equal, x[1], y[1])) and
            all(map(torch.equal, x[2], y[2])) for x, y in zip(a, b))

    first = batches(seed=7, workers=2)
    assert len(first) == 2
    assert same(first, batches(seed=7, workers=2))
    assert not same(first, batches(seed=8, workers=2))


# fewer visible pixels than min_visible_px make an annotated object an ignore region, as the
# generator's annotation.min_visible_px does: in exact_labels (after augmentation) and in the
# scene's own labels (without)
def test_too_few_pixels_become_ignore_regions():
    from stackgen.augment import exact_labels

    instance_map = np.zeros((20, 20), dtype=np.uint16)
    instance_map[2:12, 2:12] = 1   # 100 pixels
    instance_map[15:17, 15:20] = 2  # 10 pixels
    args = (instance_map, np.array([1, 2]), np.array([100, 10]), np.array([True, True]),
            np.array([False, False]), 0.3)
    assert exact_labels(*args)["iscrowd"].tolist() == [0, 0]
    assert exact_labels(*args, None, 16)["iscrowd"].tolist() == [0, 1]
    assert exact_labels(*args, None, 101)["iscrowd"].tolist() == [1, 1]
    scene = scenes()[0]
    for least, crowd in ((1, scene.ignored), (10 ** 6, scene.annotated | scene.ignored)):
        _, target = sgt.StreamDataset(URL, min_visible_px=least, **OPEN).sample(scene)
        candidates = np.flatnonzero(scene.annotated | scene.ignored)
        assert target["iscrowd"].tolist() == crowd[candidates].astype(int).tolist()
    with pytest.raises(ValueError):
        sgt.StreamDataset(URL, min_visible_px=0, **OPEN)


# a user's transforms run on every sample after stackgen's augmentation, through DataLoader
# workers too; a transforms that is not callable is refused
def test_transforms_run_on_every_sample():
    def darker(image, target):
        target = dict(target, seen=torch.tensor(1))
        return image * 0.5, target

    plain = [image for image, _ in sgt.StreamDataset(URL, **OPEN)]
    dataset = sgt.StreamDataset(URL, transforms=darker, **OPEN)
    loader = DataLoader(dataset, batch_size=1, num_workers=2, collate_fn=sgt.collate)
    changed = sorted(((t["scene"][1].item(), images[0]) for images, targets in loader
                      for t in targets if t["seen"].item() == 1), key=lambda item: item[0])
    assert len(changed) == len(plain) == 4
    for (_, image), before in zip(changed, plain):
        assert torch.equal(image, before * 0.5)
    with pytest.raises(ValueError):
        sgt.StreamDataset(URL, transforms="darker", **OPEN)


# a gray image: one channel in [0, 1]; the default replicates a gray camera to three channels
def test_grayscale_option():
    dataset = sgt.StreamDataset(URL, grayscale=True, **OPEN)
    scene = scenes()[0]
    image, _ = dataset.sample(scene)
    assert image.shape == (1, scene.height, scene.width) and image.dtype == torch.float32
    expected = cv2.cvtColor(scene.rgb, cv2.COLOR_RGB2GRAY).astype(np.float32) / 255
    assert np.allclose(image[0].numpy(), expected)
    image, _ = sgt.StreamDataset(URL, **OPEN).sample(scene)
    assert image.shape == (3, scene.height, scene.width)


# a recording repeats a scene for each use; its replay hands every event out, the n-th repeat as
# use n, and a plain stream of the same log hands each scene out once
def test_recording_replays_its_uses(tmp_path):
    log = tmp_path / "run.lcmlog"
    recorder = stackgen.LogRecorder(log)
    order = []
    for scene in scenes():
        for _ in range(1 + scene.seq % 2):
            recorder.append(scene)
            order.append(scene.seq)
    replay = sgt.StreamDataset("file://%s" % log, replay=True)
    assert [(t["scene"][1].item(), t["scene"][2].item()) for _, t in replay] == [
        (seq, order[:i].count(seq)) for i, seq in enumerate(order)]
    assert [s.seq for s in stackgen.Stream("file://%s" % log)] == sorted(set(order))


def augment_input(scene, px_count_all):
    """What StreamDataset hands Augment for `scene`, every instance a candidate."""
    everyone = list(range(scene.num_instances))
    return {"image": scene.rgb, "instance_map": scene.instance_map, "depth": None, "K": scene.K,
            "instance_ids": scene.instance_ids, "px_count_all": px_count_all,
            "annotated": scene.annotated, "ignored": scene.ignored, "bbox_obj": scene.bbox_obj,
            "bbox_visib": scene.bbox_visib,
            "boxed_masks_obj": lambda: scene.boxed_masks_obj(everyone)}


# px_count_all after a transform is the count of the whole moved full mask, in the image or out
# of it: the same as resampling each full mask over a canvas that holds the whole moved image,
# through the same maps (what Augment does on each object's box only, for speed)
def test_full_size_counts_the_whole_moved_mask():
    augment = sgt.Augment(**EVERYTHING)
    compared = 0
    for seed in range(60):
        for scene in scenes():
            out = augment(augment_input(scene, scene.px_count_all),
                          np.random.default_rng(seed))
            a = out["affine"]
            if np.allclose(a, np.eye(3)):
                continue
            corners = np.array([[-1, -1, 1], [scene.width, -1, 1], [-1, scene.height, 1],
                                [scene.width, scene.height, 1]]) @ a.T
            x0, y0 = np.floor(corners[:, :2].min(axis=0)).astype(int) - 1
            x1, y1 = np.ceil(corners[:, :2].max(axis=0)).astype(int) + 2
            map_x, map_y = augment._maps(np.linalg.inv(a), x0, x1, y0, y1)
            for k, full in enumerate(scene.masks_obj()):
                canvas = cv2.remap(full, map_x, map_y, cv2.INTER_NEAREST,
                                   borderMode=cv2.BORDER_CONSTANT, borderValue=0)
                assert out["px_count_all"][k] == cv2.countNonZero(canvas)
                compared += 1
    assert compared > 1000


# an object the scene's own image edge cut counts pixels outside the image that its full mask
# (over the image only) cannot show: after a transform they are still counted, scaled by the
# map's area factor |det A|, on top of the moved mask's pixels
def test_part_beyond_the_scene_image_keeps_its_share():
    augment = sgt.Augment(**EVERYTHING)
    compared = 0
    for seed in range(20):
        for scene in scenes():
            beyond = np.where(scene.px_count_all > 0, 1000, 0)
            whole = augment(augment_input(scene, scene.px_count_all), np.random.default_rng(seed))
            cut = augment(augment_input(scene, scene.px_count_all + beyond),
                          np.random.default_rng(seed))
            a = whole["affine"]
            if np.allclose(a, np.eye(3)):
                assert list(cut["px_count_all"]) == list(whole["px_count_all"] + beyond)
                continue
            factor = abs(np.linalg.det(a[:2, :2]))
            assert list(cut["px_count_all"]) == [
                w + (round(b * factor) if b > 0 else 0)
                for w, b in zip(whole["px_count_all"], beyond)]
            compared += 1
    assert compared > 20
