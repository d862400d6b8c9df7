"""research/eval_detector.py: bad command lines are refused in one line, and tiny runs (two steps on
a two-image COCO folder, the Mask R-CNN modes and the quick mode) train, score and write JSON."""

import json
import os
import subprocess
import sys

import cv2
import numpy as np
import pytest

ROOT = os.environ.get("STACKGEN_SOURCE_DIR",
                      os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(
                          os.path.abspath(__file__))))))
PROGRAM = os.path.join(ROOT, "research", "eval_detector.py")


def run(*args):
    return subprocess.run([sys.executable, PROGRAM, *args], capture_output=True, text=True,
                          timeout=600)


def make_coco(folder):
    """Two 480 x 640 images, each with two bright squares on grey, one of them an ignore region."""
    os.makedirs(os.path.join(folder, "images"))
    images, annotations = [], []
    for i in range(2):
        image = np.full((480, 640, 3), 90, np.uint8)
        for k, (x, y) in enumerate([(100 + 40 * i, 120), (380, 260 - 30 * i)]):
            image[y:y + 90, x:x + 90] = 220
            mask = np.zeros((480, 640), np.uint8)
            mask[y:y + 90, x:x + 90] = 1
            flat = mask.flatten(order="F")
            edges = np.concatenate(([0], np.flatnonzero(np.diff(flat)) + 1, [flat.size]))
            annotations.append({"id": 10 * i + k + 1, "image_id": i + 1, "category_id": 1,
                                "iscrowd": k, "bbox": [x, y, 90, 90], "area": 8100,
                                "segmentation": {"counts": np.diff(edges).tolist(),
                                                 "size": [480, 640]}})
        cv2.imwrite(os.path.join(folder, "images", "%d.png" % i), image)
        images.append({"id": i + 1, "file_name": "%d.png" % i, "width": 640, "height": 480})
    with open(os.path.join(folder, "annotations.json"), "w") as file:
        json.dump({"images": images, "annotations": annotations,
                   "categories": [{"id": 1, "name": "square"}]}, file)


def test_bad_command_lines_say_what_and_exit_2(tmp_path):
    missing = run("--config", str(tmp_path / "missing.pbtxt"))
    assert missing.returncode == 2
    assert "missing.pbtxt" in missing.stderr and len(missing.stderr.strip().splitlines()) == 1
    config = os.path.join(ROOT, "config", "default.pbtxt")
    not_coco = run("--config", config, "--test", str(tmp_path))
    assert not_coco.returncode == 2 and "annotations.json" in not_coco.stderr
    alone = run("--config", config, "--no-held-out")
    assert alone.returncode == 2 and "--no-held-out" in alone.stderr


def test_a_work_folders_set_of_another_count_or_config_is_refused(tmp_path):
    """--work-dir keeps the sets it made; one stamped as made from another config text, scene
    count or seed, or not stamped at all (even with the scene count asked for), is refused in one
    line naming it, before anything is made or trained, rather than trained on."""
    work, tests = str(tmp_path / "work"), str(tmp_path / "squares")
    make_coco(tests)
    kept = os.path.join(work, "train-0-default-seed-3")
    make_coco(kept)  # a set from before stamps: two scenes
    args = ("--mode", "quick", "--config", os.path.join(ROOT, "config", "default.pbtxt"),
            "--test", tests, "--no-held-out", "--seeds", "3", "--steps", "2", "--threads", "2",
            "--work-dir", work)
    unstamped = run(*args, "--train-scenes", "2")
    assert unstamped.returncode == 1, unstamped.stderr
    assert kept in unstamped.stderr and "has no made-from.txt" in unstamped.stderr
    assert len(unstamped.stderr.strip().splitlines()) == 1
    with open(os.path.join(kept, "made-from.txt"), "w") as file:
        file.write("seed 3, 2 scenes, config:\npart { count: 5 }\n")
    other = run(*args, "--train-scenes", "2")
    assert other.returncode == 1, other.stderr
    assert kept in other.stderr and "another config" in other.stderr
    assert not os.path.exists(os.path.join(work, "errors"))  # nothing trained or scored


def test_a_tiny_run_trains_scores_and_writes_json(tmp_path):
    folder = str(tmp_path / "squares")
    make_coco(folder)
    out = str(tmp_path / "results.json")
    result = run("--config", os.path.join(ROOT, "config", "default.pbtxt"), "--train-dir", folder,
                 "--test", folder, "--no-held-out", "--steps", "2", "--scale", "0.25",
                 "--threads", "2", "--out", out)
    assert result.returncode == 0, result.stderr
    assert "MIoU" in result.stdout
    with open(out) as file:
        written = json.load(file)
    (scores,) = written["results"]
    assert scores["images"] == 2
    # one real square per image: found or missed, the ignore regions never count
    assert scores["tp"] + scores["fn"] == 2
    assert written["steps"] == 2 and written["mode"] == "cpu"


def test_quick_mode_flags_are_checked():
    config = os.path.join(ROOT, "config", "default.pbtxt")
    cpu_seeds = run("--config", config, "--seeds", "0 1")
    assert cpu_seeds.returncode == 2 and "--seeds is for --mode quick" in cpu_seeds.stderr
    twice = run("--config", config, "--mode", "quick", "--seeds", "1 1")
    assert twice.returncode == 2 and "distinct" in twice.stderr
    cpu_errors = run("--config", config, "--errors", "/tmp/nowhere")
    assert cpu_errors.returncode == 2 and "--mode quick" in cpu_errors.stderr
    cpu_levels = run("--config", config, "--unet-levels", "5")
    assert cpu_levels.returncode == 2 and "--mode quick" in cpu_levels.stderr
    cpu_tta = run("--config", config, "--tta")
    assert cpu_tta.returncode == 2 and "--mode quick" in cpu_tta.stderr
    too_deep = run("--config", config, "--mode", "quick", "--unet-levels", "7")
    assert too_deep.returncode == 2 and "2..6" in too_deep.stderr


def test_a_tiny_quick_run_scores_summarises_and_draws_the_errors(tmp_path):
    folder = str(tmp_path / "squares")
    make_coco(folder)
    # an independent set's README names each image's kind of scene
    with open(os.path.join(folder, "README.txt"), "w") as file:
        file.write("Made by hand.\n\nimages/0.png: white tote (0.85, 0.85), 200 mm; 2 parts\n"
                   "images/1.png: blue tote, 210 mm; 2 parts\n")
    out, work = str(tmp_path / "results.json"), str(tmp_path / "work")
    result = run("--mode", "quick", "--config", os.path.join(ROOT, "config", "default.pbtxt"),
                 "--train-dir", folder, "--test", folder, "--no-held-out", "--seeds", "3",
                 "--steps", "2", "--threads", "2", "--work-dir", work, "--worst", "1",
                 "--unet-levels", "5", "--out", out)
    assert result.returncode == 0, result.stderr
    assert "foreground IoU" in result.stdout and "spread" in result.stdout
    with open(out) as file:
        written = json.load(file)
    assert written["mode"] == "quick" and written["seeds"] == [3] and written["steps"] == 2
    assert written["unet_levels"] == 5
    (scores,) = written["results"]
    assert scores["seed"] == 3 and scores["images"] == 2
    assert 0 <= scores["foreground_iou"] <= 1
    assert scores["tp"] + scores["fn"] == 2  # the ignore squares count neither way
    (summary,) = written["summaries"]
    assert summary["foreground_iou"]["mean"] == scores["foreground_iou"]
    assert summary["foreground_iou"]["spread"] == 0  # one seed
    assert set(summary["pixels"]) >= {"false_negative", "false_positive"}
    # each kind of scene scores as its image did
    assert "by the kind of scene" in result.stdout
    assert {k["kind"]: k["foreground_iou"] for k in summary["by_kind"]} == {
        "white tote": scores["per_image_iou"][0], "blue tote": scores["per_image_iou"][1]}
    assert [k["images"] for k in summary["by_kind"]] == [1, 1]
    # the pictures go where the instrument's levels and steps and the first seed name them
    errors = os.path.join(work, "errors", "unet5-2-steps-seed-3")
    (picture,) = os.listdir(errors)
    assert picture.endswith(".jpg") and cv2.imread(os.path.join(errors, picture)) is not None
    # --tta: said, written down, and its pictures kept apart from those above
    result = run("--mode", "quick", "--config", os.path.join(ROOT, "config", "default.pbtxt"),
                 "--train-dir", folder, "--test", folder, "--no-held-out", "--seeds", "3",
                 "--steps", "2", "--threads", "2", "--work-dir", work, "--worst", "1",
                 "--unet-levels", "5", "--tta", "--out", out)
    assert result.returncode == 0, result.stderr
    assert "eight quarter turns and mirror images" in result.stdout
    with open(out) as file:
        assert json.load(file)["tta"] is True
    assert os.listdir(errors + "-tta") == [picture]


def test_kinds_of_scene_pool_the_seeds_and_need_every_image_named(tmp_path):
    sys.path.insert(0, os.path.join(ROOT, "research"))
    import eval_detector  # noqa: E402
    from stackgen.coco import CocoDataset

    # two seeds of three images, two of them white totes: the lowest kind first
    kinds = eval_detector.by_kind([[0.2, 0.9, 0.4], [0.4, 0.7, 0.6]],
                                  ["white tote", "blue tote", "white tote"])
    assert [(kind, images) for kind, _, images in kinds] == [("white tote", 2), ("blue tote", 1)]
    assert [mean for _, mean, _ in kinds] == pytest.approx([0.4, 0.8])
    folder = str(tmp_path / "squares")
    make_coco(folder)
    dataset = CocoDataset(folder)
    assert eval_detector.scene_kinds(folder, dataset) is None  # no README.txt
    with open(os.path.join(folder, "README.txt"), "w") as file:
        file.write("images/1.png: steel tote (grey 0.7), 200 mm\n")
    assert eval_detector.scene_kinds(folder, dataset) is None  # image 0 not named
    with open(os.path.join(folder, "README.txt"), "a") as file:
        file.write("images/0.png: red tote, 190 mm\n")
    assert eval_detector.scene_kinds(folder, dataset) == ["red tote", "steel tote"]


def test_workers_read_the_same_batches_as_the_training_process(tmp_path):
    """--workers: the batches read ahead by worker processes are those read between steps, image
    for image and flip for flip, and every image comes once per pass of the plan."""
    from types import SimpleNamespace

    import torch

    sys.path.insert(0, os.path.join(ROOT, "research"))
    import eval_detector  # noqa: E402
    from stackgen.coco import CocoDataset

    plan = eval_detector.batch_plan(5, 4, 3, seed=7)
    assert [len(batch) for batch in plan] == [3, 3, 3, 3]
    passes = [index for batch in plan for index, _ in batch]
    assert sorted(passes[:5]) == list(range(5)) and sorted(passes[5:10]) == list(range(5))
    assert {flip for batch in plan for _, flip in batch} == {False, True}
    folder = str(tmp_path / "squares")
    make_coco(folder)
    dataset = CocoDataset(folder)
    read = {}
    for workers in (0, 2):
        args = SimpleNamespace(steps=6, batch_size=3, seed=7, workers=workers)
        read[workers] = list(eval_detector.training_batches(args, dataset))
    assert len(read[0]) == len(read[2]) == 6
    flips = 0
    for here, ahead in zip(read[0], read[2]):
        assert len(here) == len(ahead) == 3
        for (image, target), (image2, target2) in zip(here, ahead):
            assert image.dtype == torch.uint8 and image.shape == (3, 480, 640)
            assert torch.equal(image, image2)
            assert target.keys() == target2.keys()
            assert all(torch.equal(target[k], target2[k]) for k in target)
            # one object per image (the other is an ignore region), its box where its mask is
            box = target["boxes"][0].int().tolist()
            assert target["masks"].shape == (1, 480, 640) and target["masks"].sum() == 8100
            assert image[0, box[1]:box[3], box[0]:box[2]].min() == 220
            flips += box[0] > 320
    assert 0 < flips
