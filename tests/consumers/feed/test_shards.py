"""stackgen.shards: stackgen-coco's webdataset shards streamed as training samples. A sample
from a shard equals StreamDataset's sample of the same scene without augmentation (image, boxes,
labels, masks, iscrowd, counts, poses); ranks and workers split the shards with none read twice;
a pipe: command reads like a file; a cut shard, a folder without shards and a failing command
are refused naming them.

CTest runs this file with Debian's /usr/bin/python3 -m pytest; PYTHONPATH is the build's
python/ folder."""

import os
import shutil

import pytest
import torch
from torch.utils.data import DataLoader

import stackgen.torch as sgt
from stackgen.shards import ShardDataset, read_shard, shard_sources

from conftest import TINY_LOG, coco_of_fixture_log


@pytest.fixture(scope="module")
def sharded(tmp_path_factory):
    """The fixture log's 4 scenes as a COCO folder with shards of one image each."""
    return coco_of_fixture_log(tmp_path_factory.mktemp("sharded") / "coco", shards=1)


def test_sample_equals_the_stream_without_augmentation(sharded):
    stream = {int(target["image_id"]): (image, target) for image, target in
              sgt.StreamDataset("file://" + TINY_LOG, open_bus=True)}
    shards = list(ShardDataset(sharded))
    assert len(shards) == 4 and sorted(stream) == sorted(int(t["image_id"]) for _, t in shards)
    for image, target in shards:
        expected_image, expected = stream[int(target["image_id"])]
        assert torch.equal(image, expected_image)
        assert len(target["labels"]) > 0
        for name in ("boxes", "labels", "masks", "iscrowd", "area", "px_count_all",
                     "px_count_visib", "instance_ids", "scene"):
            assert torch.equal(target[name].to(expected[name].dtype), expected[name]), name
        for name in ("visib_fract", "camera_from_object", "world_from_object", "K"):
            assert torch.allclose(target[name].double(), expected[name].double(), atol=1e-6), name


def test_ranks_and_workers_split_the_shards(sharded):
    sources = shard_sources(sharded)
    # generator 2's seqs 0..3, one image a shard: (2 * 10^6 + 0) * 1000 + seq
    assert [os.path.basename(s) for s in sources] == ["shard-%06d.tar" % (2000000000 + seq)
                                                      for seq in range(4)]
    seen = []
    for rank in (0, 1):
        loader = DataLoader(ShardDataset(sharded, rank=rank, world_size=2), batch_size=1,
                            num_workers=2, collate_fn=sgt.collate)
        ids = [int(targets[0]["image_id"]) for _, targets in loader]
        assert len(ids) == 1 * 2  # 4 shards of one image, 2 ranks of 2 workers: one each
        seen += ids
    assert len(set(seen)) == 4


def test_a_command_reads_like_a_file(sharded):
    source = shard_sources(sharded)[0]
    by_file = list(read_shard(source))
    by_pipe = list(read_shard("pipe:cat '%s'" % source))
    assert [key for key, _, _ in by_pipe] == [key for key, _, _ in by_file] == ["2_000000"]
    assert (by_pipe[0][1] == by_file[0][1]).all() and by_pipe[0][2] == by_file[0][2]


def test_bad_shards_are_refused_naming_them(sharded, tmp_path):
    source = shard_sources(sharded)[0]
    cut = tmp_path / "cut.tar"
    with open(source, "rb") as whole:
        cut.write_bytes(whole.read()[:1500])
    with pytest.raises(ValueError, match="cut.tar: not a whole tar shard"):
        list(read_shard(str(cut)))
    empty = tmp_path / "empty"
    shutil.copytree(sharded, empty, ignore=shutil.ignore_patterns("shards"))
    with pytest.raises(ValueError, match="empty: no webdataset shards"):
        ShardDataset(str(empty))
    with pytest.raises(ValueError, match="the command exited with 1"):
        list(read_shard("pipe:cat %s/none.tar" % tmp_path))
    with pytest.raises(ValueError, match="not a dataset folder, a .tar shard"):
        shard_sources(str(tmp_path / "nothing"))
