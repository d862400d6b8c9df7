"""The Python feed end to end: real generators (stackgen) and stackgen-coco as separate processes,
over real UDP multicast on a port of the test's own, read by stackgen.Stream and
stackgen.torch.StreamDataset."""

import collections
import json
import os

import cv2
import numpy as np
import pytest
from torch.utils.data import DataLoader

import stackgen
import stackgen.torch as sgt
from conftest import BIN, TINY_CONFIG, TINY_LOG, free_url, generator_argv, quick_config

CONFIG = TINY_CONFIG  # the generators' config: the tiny one, one lighting environment (below)


@pytest.fixture(scope="module", autouse=True)
def quick_tiny(tmp_path_factory):
    """Every generator of this file on conftest.quick_config: a generator prepares the config's
    lighting environments when it starts, most of a short run's time."""
    global CONFIG
    CONFIG = quick_config(tmp_path_factory.mktemp("config"))
    yield CONFIG
    CONFIG = TINY_CONFIG


def quick_generator(url, count, cache_dir, *extra, **options):
    """A generator's command line (conftest.generator_argv) on that config."""
    return generator_argv(url, count, cache_dir, *extra, config=CONFIG, **options)


# the scenes a reliable stream hands out are the ones stackgen-coco stores for the same run:
# images, visible and full masks, boxes, poses and visibility bit for bit; and the torch
# target of a scene (no augmentation) holds exactly those labels
def test_stream_equals_what_stackgen_coco_stores(tmp_path, processes):
    url, count = free_url(), 6
    coco = processes([os.path.join(BIN, "stackgen-coco"), "--out", tmp_path / "coco", "--count",
                      count, "--lcm-url", url], "coco")
    assert coco.wait_for_output("listening", 10), coco.stderr()
    with stackgen.Stream(url, reliable=True, count=count, timeout=60, depth=True) as stream:
        generator = processes(quick_generator(url, count, tmp_path / "cache"), "stackgen")
        scenes = list(stream)
    assert generator.wait(60) == 0, generator.stderr()
    assert coco.wait(60) == 0, coco.stderr()
    assert sorted((s.generator_id, s.seq) for s in scenes) == [(0, k) for k in range(count)]

    with open(tmp_path / "coco" / "annotations.json") as file:
        dataset = json.load(file)
    images = {image["id"]: image for image in dataset["images"]}
    annotations = collections.defaultdict(dict)
    for annotation in dataset["annotations"]:
        annotations[annotation["image_id"]][annotation["instance_id"]] = annotation
    torch_view = sgt.StreamDataset("file://" + TINY_LOG)
    compared = 0
    for scene in scenes:
        image_id = scene.generator_id * 100000000 + scene.seq + 1
        stored = cv2.imread(str(tmp_path / "coco" / "images" / images[image_id]["file_name"]),
                            cv2.IMREAD_COLOR)
        assert np.array_equal(cv2.cvtColor(stored, cv2.COLOR_BGR2RGB), scene.rgb)
        assert scene.depth_mm.dtype == np.float32
        assert np.all(scene.depth_mm[scene.instance_map > 0] > 0)
        masks_visib = scene.masks_visib()
        masks_obj = scene.masks_obj()
        height, width = scene.height, scene.width
        for k, instance_id in enumerate(scene.instance_ids):
            annotation = annotations[image_id].get(int(instance_id))
            labelled = scene.annotated[k] or scene.ignored[k]
            assert (annotation is not None) == labelled
            if annotation is None:
                continue
            assert np.array_equal(masks_visib[k], stackgen.decode_rle(
                annotation["segmentation"]["counts"], height, width))
            assert np.array_equal(masks_obj[k], stackgen.decode_rle(
                annotation["amodal_segmentation"]["counts"], height, width))
            assert np.array_equal(masks_visib[k], (scene.instance_map == instance_id))
            assert annotation["bbox"] == scene.bbox_visib[k].tolist()
            assert annotation["amodal_bbox"] == scene.bbox_obj[k].tolist()
            pose = scene.camera_from_object[k]
            assert annotation["cam_R_m2c"] == pose[:3, :3].ravel().tolist()
            assert annotation["cam_t_m2c"] == pose[:3, 3].tolist()
            assert annotation["world_t_m2w"] == scene.world_from_object[k][:3, 3].tolist()
            assert annotation["visib_fract"] == scene.visib_fract[k]
            assert annotation["iscrowd"] == int(scene.ignored[k])
            assert annotation["category_id"] == scene.class_ids[k]
            compared += 1
        # the torch target, not augmented, holds the same labels
        _, target = torch_view.sample(scene)
        for row, instance_id in enumerate(target["instance_ids"].tolist()):
            k = int(np.flatnonzero(scene.instance_ids == instance_id)[0])
            x, y, w, h = scene.bbox_visib[k]
            assert target["boxes"][row].tolist() == [x, y, x + w, y + h]
            assert np.array_equal(target["masks"][row].numpy(), masks_visib[k])
            assert target["iscrowd"][row] == int(scene.ignored[k])
            assert target["visib_fract"][row] == np.float32(scene.visib_fract[k])
            assert np.array_equal(target["camera_from_object"][row].numpy(),
                                  scene.camera_from_object[k])
    assert compared == len(dataset["annotations"]) > 0


# a 3D camera's depth reaches the learner beside the exact one: holes where the exact depth has
# a surface, and its organised point cloud is the back-projection of each pixel, NaN at holes;
# and the grasps (the tiny config has both): suction on annotated instances, each one's best
# first, unit normals facing the camera, one proof per scene; parallel jaws no wider than they
# open, coming in perpendicular to the closing line, inside the friction cones
def test_stream_carries_depth_sensor_and_grasps(tmp_path, processes):
    url, count = free_url(), 2
    with stackgen.Stream(url, reliable=True, count=count, timeout=60, depth=True) as stream:
        generator = processes(quick_generator(url, count, tmp_path / "cache"), "stackgen")
        scenes = list(stream)
    assert generator.wait(60) == 0, generator.stderr()
    assert len(scenes) == count
    for scene in scenes:
        assert scene.has_depth_sensor
        sensor, exact = scene.depth_sensor_mm, scene.depth_mm
        assert sensor.dtype == np.float32 and sensor.shape == exact.shape
        surface = exact > 0
        holes = (sensor == 0) & surface
        assert 0 < holes.sum() < surface.sum() / 2
        assert np.all(sensor[~surface] == 0)
        measured = sensor > 0
        # noise 0.2 mm at 1 m and 0.1 mm steps; flying pixels (a 160 x 120 picture is much edge)
        assert np.percentile(np.abs(sensor - exact)[measured], 80) < 0.2  # mm
        cloud = scene.point_cloud()
        assert cloud.shape == (scene.height, scene.width, 3) and cloud.dtype == np.float32
        assert np.all(np.isnan(cloud[~measured]))
        assert np.array_equal(cloud[..., 2][measured], sensor[measured])
        K = scene.K
        v, u = np.nonzero(measured)
        k = len(u) // 2
        assert abs(cloud[v[k], u[k], 0] - (u[k] - K[0, 2]) * sensor[v[k], u[k]] / K[0, 0]) < 1e-3
        exact_cloud = scene.point_cloud(sensor=False)
        assert np.array_equal(exact_cloud[..., 2][surface], exact[surface])

        grasps = scene.suction_grasps
        annotated = set(scene.instance_ids[scene.annotated].tolist())
        assert len(grasps["rank"]) > 0
        assert set(grasps["instance_id"].tolist()) <= annotated
        assert np.allclose(np.linalg.norm(grasps["normal"], axis=1), 1, atol=1e-6)
        assert np.all(np.sum(grasps["normal"] * grasps["point_mm"], axis=1) < 0)  # facing us
        assert np.all((grasps["seal"] >= 0) & (grasps["seal"] <= 1))
        for instance_id in set(grasps["instance_id"].tolist()):
            ranks = grasps["rank"][grasps["instance_id"] == instance_id]
            assert sorted(ranks.tolist()) == list(range(len(ranks)))
        u, v = grasps["uv"][:, 0], grasps["uv"][:, 1]
        assert np.array_equal(scene.instance_map[v, u], grasps["instance_id"])
        assert (grasps["proof"] != 0).sum() == 1
        jaws = scene.jaw_grasps
        assert len(jaws["rank"]) > 0
        assert set(jaws["instance_id"].tolist()) <= annotated
        width = np.linalg.norm(jaws["point_b_mm"] - jaws["point_a_mm"], axis=1)
        assert np.allclose(width, jaws["width_mm"]) and np.all(width <= 80 + 1e-6)
        closing = (jaws["point_b_mm"] - jaws["point_a_mm"]) / width[:, None]
        assert np.all(np.abs(np.sum(closing * jaws["approach"], axis=1)) < 1e-6)
        assert np.all(jaws["cone_margin_deg"] > 0)


# a reliable stream that drops 30 % of what it receives (and a generator that drops 10 % of the
# credits and resend requests) still gets every scene, exactly once. (At 10 %, which messages
# are dropped shifts with timing, as status messages interleave, and now and then none of the 16
# scenes was: 0.9^16 = 19 %, nothing to resend. At 30 % that is 0.7^16 = 0.3 %.)
def test_reliable_stream_misses_nothing_under_loss(tmp_path, processes):
    url, count = free_url(), 16
    with stackgen.Stream(url, reliable=True, count=count, timeout=60, fault_drop=0.3) as stream:
        generator = processes(quick_generator(url, count, tmp_path / "cache", "--fault-drop",
                                              "0.1"), "stackgen")
        seqs = [scene.seq for scene in stream]
    # the counters after close: while live they are refreshed every 20 ms, so a scene asked
    # for again and handed out last may still count as lost for that long
    counters = stream.counters
    assert generator.wait(60) == 0, generator.stderr()
    assert sorted(seqs) == list(range(count))
    assert counters["fault_dropped"] > 0
    assert counters["reasked"] > 0
    assert counters["lost"] == 0


# a best-effort stream whose reader stops reading never holds the generator back: the generator
# finishes on its own, held back 0 s, while the stream drops what its reader is too slow for
def test_best_effort_stream_never_holds_the_generator(tmp_path, processes):
    url, count = free_url(), 10
    with stackgen.Stream(url, reliable=False, queue=2, timeout=60) as stream:
        generator = processes(quick_generator(url, count, tmp_path / "cache",
                                              "--no-consumer-ok"), "stackgen")
        first = stream.next(timeout=60)
        assert generator.wait(60) == 0, generator.stderr()
        counters = stream.counters
    assert first is not None
    assert "held back 0.0 s by reliable consumers" in generator.stdout()
    assert counters["dropped_behind"] > 0
    assert counters["queued"] <= 2


# two DataLoader workers on one live bus split it: every scene reaches the training loop exactly
# once (a scene that reached both workers would come out twice)
def test_two_workers_never_see_the_same_scene(tmp_path, processes):
    url, count = free_url(), 12
    dataset = sgt.StreamDataset(url, count=count, timeout=60, window=4)
    loader = DataLoader(dataset, batch_size=1, num_workers=2, collate_fn=sgt.collate)
    batches = iter(loader)
    generator = processes(quick_generator(url, count, tmp_path / "cache"), "stackgen")
    keys = [tuple(target["scene"][:2].tolist()) for _, targets in batches for target in targets]
    assert generator.wait(60) == 0, generator.stderr()
    assert sorted(keys) == [(0, seq) for seq in range(count)]


# two ranks of a torch.distributed job (gloo on the CPU, two real processes, each with two
# DataLoader workers) take disjoint shards of one generator: rank r's workers the seqs with
# seq % 4 in {2r, 2r + 1}, found from torch.distributed without being told; and the explicit
# rank/world_size arguments are checked
RANK_SCRIPT = """
import json, os, sys
import torch.distributed as dist
from torch.utils.data import DataLoader
import stackgen.torch as sgt
dist.init_process_group("gloo", init_method="file://" + sys.argv[2], rank=int(sys.argv[3]),
                        world_size=2)
dataset = sgt.StreamDataset(sys.argv[1], count=8, timeout=60, window=4)
loader = DataLoader(dataset, batch_size=1, num_workers=2, collate_fn=sgt.collate)
keys = [target["scene"][:2].tolist() for _, targets in loader for target in targets]
json.dump(keys, open(sys.argv[4], "w"))
dist.barrier()
"""


def test_ranks_never_see_the_same_scene(tmp_path, processes):
    import subprocess
    import sys

    url = free_url()
    # a generator that runs until stopped: each rank's streams take their shards from the scene
    # they first hear on
    generator = processes(quick_generator(url, 0, tmp_path / "cache"), "stackgen")
    (tmp_path / "rank.py").write_text(RANK_SCRIPT)
    ranks = [subprocess.Popen([sys.executable, str(tmp_path / "rank.py"), url,
                               str(tmp_path / "rendezvous"), str(rank),
                               str(tmp_path / ("rank%d.json" % rank))],
                              stderr=subprocess.PIPE, text=True) for rank in (0, 1)]
    for rank in ranks:
        assert rank.wait(timeout=300) == 0, rank.stderr.read()
    generator.popen.send_signal(__import__("signal").SIGINT)
    assert generator.wait(60) == 0, generator.stderr()
    keys = [json.loads((tmp_path / ("rank%d.json" % rank)).read_text()) for rank in (0, 1)]
    for rank, taken in enumerate(keys):
        assert len(taken) == 4 and len({tuple(key) for key in taken}) == 4, taken
        assert {seq % 4 for _, seq in taken} <= {2 * rank, 2 * rank + 1}, (rank, taken)
    assert not {tuple(key) for key in keys[0]} & {tuple(key) for key in keys[1]}
    for bad in (dict(rank=1), dict(rank=2, world_size=2), dict(rank=0, world_size=True)):
        with pytest.raises(ValueError):
            sgt.StreamDataset(url, **bad)


# with reuse, a learner faster than the generator uses scenes again while it waits for new ones:
# each scene at most `reuse` times, its uses numbered 0, 1, ..., and the factor above 1
def test_reuse_keeps_a_fast_learner_busy(tmp_path, processes):
    url, count, reuse = free_url(), 4, 3
    dataset = sgt.StreamDataset(url, count=count, reuse=reuse, timeout=60)
    generator = processes(quick_generator(url, count, tmp_path / "cache"), "stackgen")
    meter = sgt.ReuseMeter()
    uses = collections.defaultdict(list)
    for _, target in dataset:
        meter.update([target])
        generator_id, seq, use = target["scene"].tolist()
        uses[(generator_id, seq)].append(use)
    assert generator.wait(60) == 0, generator.stderr()
    assert sorted(uses) == [(0, seq) for seq in range(count)]
    for key, numbers in uses.items():
        assert numbers == list(range(len(numbers))) and len(numbers) <= reuse, (key, numbers)
    assert meter.scenes == count
    assert meter.factor > 1


# a reliable stream that attaches to a generator which has been running for a while takes it
# from the scene it first hears, lossless from there on; the generator is not made to go back
# over its history (a writer would collect it from seq 0, regenerating what left its ring: a
# ring of 4 scenes here, so that 8 scenes are history enough)
def test_reliable_stream_joins_a_running_generator(tmp_path, processes):
    import signal
    import time

    url = free_url()
    monitor = stackgen.StatusMonitor(url)
    generator = processes(quick_generator(url, 0, tmp_path / "cache", "--resend-ring", "4"),
                          "stackgen")
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        published = [s["next_seq"] for s in monitor.latest("stackgen")]
        if published and published[0] > 8:
            break
        time.sleep(0.1)
    with stackgen.Stream(url, reliable=True, count=6, timeout=60) as stream:
        seqs = [scene.seq for scene in stream]
    assert seqs[0] > 8
    assert seqs == list(range(seqs[0], seqs[0] + 6))
    time.sleep(1.5)  # a status of the generator after the stream left
    generator.popen.send_signal(signal.SIGINT)
    assert generator.wait(30) == 0, generator.stderr()
    assert " 0 regenerated" in generator.stdout()


# a training loop that stops early ends its DataLoader workers in the middle of their stream:
# the worker's reliable stream is closed on the way out and tells the generator it leaves, so
# the generator stops waiting for it at once instead of after --consumer-timeout
def test_worker_that_ends_early_leaves(tmp_path, processes):
    import time

    url = free_url()
    monitor = stackgen.StatusMonitor(url)
    generator = processes(quick_generator(url, 0, tmp_path / "cache", "--consumer-timeout",
                                          "60"), "stackgen")
    loader = DataLoader(sgt.StreamDataset(url, timeout=60), batch_size=1, num_workers=1,
                        collate_fn=sgt.collate)

    def consumers():
        return [s["reliable_consumers"] for s in monitor.latest("stackgen")]

    batches = iter(loader)
    for _ in range(3):
        next(batches)
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and consumers() != [1]:
        time.sleep(0.1)
    assert consumers() == [1]
    del batches  # the worker process ends
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline and consumers() != [0]:
        time.sleep(0.1)
    assert consumers() == [0]
    assert generator.popen.poll() is None


# a copy of a scene that fails the checks (a stranger's, or damaged) tells a reliable stream
# nothing: here a bad scene 5/500 arrives first and must not make the stream join generator 5 at
# seq 500 (counting 0..499 as done), so the real scenes 0.. are still taken
def test_bad_copy_does_not_move_where_a_stream_joins(tmp_path, processes):
    import subprocess
    import time

    from test_errors import log_events

    url = free_url()
    raw = [data for channel, data in log_events(TINY_LOG) if channel == "STACKGEN_SCENE"]
    stranger = stackgen.msg.scene.decode(raw[0])
    stranger.header.generator_id = 5
    stranger.header.seq = 500
    stranger.instances[0].class_id = 0
    log = tmp_path / "stranger.lcmlog"
    stackgen._native.LogAppender(str(log)).append("STACKGEN_SCENE", stranger.encode(), 0)
    # the stranger's copy is a recording played onto the bus: only a stream told that it reads
    # a replay takes it (a live one refuses it before any check)
    with stackgen.Stream(url, reliable=True, count=3, timeout=60, replay=True) as stream:
        subprocess.run(["lcm-logplayer", "-l", url, str(log)], check=True, timeout=30)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and stream.counters["bad_messages"] == 0:
            time.sleep(0.05)
        assert stream.counters["bad_messages"] == 1
        processes(quick_generator(url, 3, tmp_path / "cache", generator_id=5), "stackgen")
        seqs = [scene.seq for scene in stream]
    assert seqs == [0, 1, 2]


# with another bus key than the generator's, a stream takes no scene, warns, and its timeout names
# the mismatch in one line (nothing it cannot verify ends it before); a reliable stream on an
# open bus (open_bus=True), which verifies nothing, stops with that line while the generator
# signs: its credits would be refused (a best-effort one reads the signed scenes); a key file
# that cannot serve is one line naming it
def test_stream_with_another_key_says_so(tmp_path, processes):
    bad = tmp_path / "short.key"
    bad.write_text("short\n")
    bad.chmod(0o600)
    with pytest.raises(stackgen.StreamError) as error:
        stackgen.Stream(free_url(), bus_key_file=str(bad))
    assert str(bad) in str(error.value) and "\n" not in str(error.value)
    other = tmp_path / "other.key"
    other.write_text("another deployment's key, 32 bytes or more of it\n")
    other.chmod(0o600)
    for options, says in ((dict(bus_key_file=str(other), reliable=False),
                           "signed with another bus key"),
                          (dict(open_bus=True, reliable=True), "runs with an open bus")):
        url = free_url()
        with stackgen.Stream(url, timeout=5, **options) as stream:
            processes(quick_generator(url, 20, tmp_path / "cache"), "stackgen")
            with pytest.raises(stackgen.StreamError) as error:
                for _ in stream:
                    pass
            counters = stream.counters
        text = str(error.value)
        assert says in text and "\n" not in text, text
        if "bus_key_file" in options:
            assert str(other) in text and counters["refused_forged"] >= 1
            assert counters["received"] == 0
