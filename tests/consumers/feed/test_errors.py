"""Bad input to the Python feed gets one clear line naming the URL, file, event or value, and the
lcm-gen Python types shipped in the package decode what the generator writes."""

import multiprocessing
import struct

import pytest

import stackgen
import stackgen.torch as sgt
from conftest import TINY_LOG, free_url

URL = "file://" + TINY_LOG
# the fixture log was recorded on an open bus (no key): it is read with open_bus=True
OPEN = dict(open_bus=True)


def one_line(error):
    text = str(error.value)
    assert "\n" not in text
    return text


def log_events(path):
    """(channel, data) of every event of an LCM log, read with the format alone."""
    events = []
    with open(path, "rb") as file:
        data = file.read()
    offset = 0
    while offset + 28 <= len(data):
        magic, _, _, channel_length, data_length = struct.unpack_from(">IqqII", data, offset)
        assert magic == 0xEDA1DA01
        offset += 28
        channel = data[offset:offset + channel_length].decode()
        offset += channel_length
        events.append((channel, data[offset:offset + data_length]))
        offset += data_length
    return events


# a missing log, a folder, and a file that is not an LCM log are refused when the stream opens
def test_missing_or_junk_log(tmp_path):
    with pytest.raises(stackgen.StreamError) as error:
        stackgen.Stream("file://%s/missing.lcmlog" % tmp_path)
    assert "missing.lcmlog" in one_line(error) and "no such file" in one_line(error)
    with pytest.raises(stackgen.StreamError) as error:
        stackgen.Stream("file://%s" % tmp_path)
    assert "is a folder" in one_line(error)
    junk = tmp_path / "junk.lcmlog"
    junk.write_bytes(b"not a log at all" * 100)
    with pytest.raises(stackgen.StreamError) as error:
        stackgen.Stream("file://%s?speed=0" % junk)
    assert str(junk) in one_line(error) and "not an LCM log" in one_line(error)
    # the dataset refuses it in the training process, before any DataLoader worker starts
    with pytest.raises(stackgen.StreamError):
        sgt.StreamDataset("file://%s" % junk)


# a log whose scene channel carries another type (or another build's scene) stops the stream
# with the file, the event and both types named; a log without scenes says what it holds
def test_scene_type_mismatch_and_log_without_scenes(tmp_path):
    labels = stackgen.msg.labels()
    labels.header = stackgen.msg.header()
    labels.camera = stackgen.msg.camera_info()
    labels.camera.world_from_camera = stackgen.msg.pose()
    wrong = tmp_path / "wrong.lcmlog"
    stackgen._native.LogAppender(str(wrong)).append("STACKGEN_SCENE", labels.encode(), 0)
    with pytest.raises(stackgen.StreamError) as error:
        list(stackgen.Stream("file://%s" % wrong))
    text = one_line(error)
    assert str(wrong) in text and "the event at byte 0" in text and "stackgen.labels" in text

    only_labels = tmp_path / "labels.lcmlog"
    appender = stackgen._native.LogAppender(str(only_labels))
    for _ in range(2):
        appender.append("STACKGEN_LABELS", labels.encode(), 0)
    with pytest.raises(stackgen.StreamError) as error:
        list(stackgen.Stream("file://%s" % only_labels))
    assert "no events on channel STACKGEN_SCENE (it has STACKGEN_LABELS x2)" in one_line(error)


# a log recorded with another bus key is one line naming both key ids, not an empty stream (and
# the first refusal is the only line on stderr); the fixture log, recorded on an open bus, is
# one line saying so without open_bus; a key and an open bus exclude each other
def test_log_of_another_key_is_one_line(tmp_path, capfd):
    other = tmp_path / "other.key"
    other.write_text("another deployment's key, 32 bytes or more of it\n")
    other.chmod(0o600)
    raw = [data for channel, data in log_events(TINY_LOG) if channel == "STACKGEN_SCENE"]
    log = tmp_path / "other.lcmlog"
    appender = stackgen._native.LogAppender(str(log), str(other))
    for data in raw:
        appender.append("STACKGEN_SCENE", data, 0)
    capfd.readouterr()
    with pytest.raises(stackgen.StreamError) as error:
        list(stackgen.Stream("file://%s" % log))
    text = one_line(error)
    assert "signed with another bus key" in text and str(log) in text
    assert len(capfd.readouterr().err.strip().splitlines()) <= 1
    assert [s.seq for s in stackgen.Stream("file://%s" % log, bus_key_file=str(other))] == [
        0, 1, 2, 3]
    with pytest.raises(stackgen.StreamError) as error:
        list(stackgen.Stream(URL))
    assert "not signed" in one_line(error) and "--open-bus" in one_line(error)
    with pytest.raises(ValueError):
        stackgen.Stream(URL, bus_key_file=str(other), open_bus=True)


# a bus URL that names no bus, or no multicast group, is refused with the URL named
def test_unusable_bus():
    for url in ("bogus://x", "udpm://10.1.2.3:7667?ttl=0"):
        with pytest.raises(stackgen.StreamError) as error:
            stackgen.Stream(url)
        assert url.split("?")[0] in one_line(error)


# nothing on the bus: StreamTimeout (also a TimeoutError) names the channel and URL
def test_timeout_names_the_bus():
    url = free_url()
    with stackgen.Stream(url, reliable=False, status=False) as stream:
        with pytest.raises(stackgen.StreamTimeout) as error:
            stream.next(timeout=0.3)
    assert isinstance(error.value, TimeoutError)
    assert "STACKGEN_SCENE" in one_line(error) and url in one_line(error)


class _Deadline(Exception):
    pass


# a signal handler that raises while the stream waits (a learner's own time limit) stops the
# wait, and its exception, not a KeyboardInterrupt, reaches the caller; the stream stays usable
def test_signal_handler_error_reaches_the_caller():
    import signal

    def on_alarm(signum, frame):
        raise _Deadline()

    url = free_url()
    previous = signal.signal(signal.SIGALRM, on_alarm)
    try:
        with stackgen.Stream(url, reliable=False, status=False) as stream:
            signal.setitimer(signal.ITIMER_REAL, 0.3)
            with pytest.raises(_Deadline):
                stream.next(timeout=20)
            with pytest.raises(stackgen.StreamTimeout):
                stream.next(timeout=0.2)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def _read_in_child(stream, queue):
    try:
        stream.next(timeout=1)
        queue.put("no error")
    except stackgen.StreamError as error:
        queue.put(str(error))


# a stream opened in one process cannot be read in another (a DataLoader worker that inherited
# it would share its socket and its scenes): the worker gets one line saying to open its own
def test_stream_cannot_be_shared_between_processes():
    stream = stackgen.Stream(URL, **OPEN)
    context = multiprocessing.get_context("fork")
    queue = context.Queue()
    child = context.Process(target=_read_in_child, args=(stream, queue))
    child.start()
    child.join(30)
    text = queue.get(timeout=5)
    assert "cannot be shared between processes" in text and "StreamDataset" in text
    assert stream.next(timeout=5) is not None  # the parent's stream still works
    stream.close()


def _close_in_child(stream, queue):
    stream.close()
    queue.put(stream.counters["handed"])


# a forked process that inherited a stream (and dropped it on the way out) neither stops the
# parent's threads nor waits on its locks: close is a no-op there and counters are empty
def test_stream_closed_in_a_forked_process():
    stream = stackgen.Stream(URL, **OPEN)
    assert stream.next(timeout=5) is not None
    context = multiprocessing.get_context("fork")
    queue = context.Queue()
    child = context.Process(target=_close_in_child, args=(stream, queue))
    child.start()
    child.join(30)
    assert child.exitcode == 0
    assert queue.get(timeout=5) == 0
    assert stream.next(timeout=5) is not None  # the parent's stream still works
    assert stream.counters["handed"] == 2
    stream.close()
    assert stream.next(timeout=5) is None  # a closed stream hands out nothing more


# values out of range are refused by name before anything opens; so is a worker count beyond
# what a stream can be split into
def test_bad_arguments(tmp_path):
    for kwargs, name in ((dict(window=0), "window"), (dict(timeout=-1), "timeout"),
                         (dict(shard=(0, 300)), "shard count"), (dict(shard=(2, 2)), "shard index"),
                         (dict(generator_ids=[70000]), "generator id"),
                         (dict(fault_drop=1.0), "fault_drop"), (dict(lcm_url=""), "lcm_url")):
        with pytest.raises(ValueError) as error:
            stackgen.Stream(**dict(dict(lcm_url=URL), **kwargs))
        assert name in one_line(error)
    with pytest.raises(stackgen.StreamError) as error:
        sgt.StreamDataset(URL)._open(0, 300)
    assert "at most 256 shards (ranks x DataLoader workers), not 300" in one_line(error)
    with pytest.raises(ValueError):
        sgt.StreamDataset(free_url(), replay=True)
    existing = tmp_path / "taken.lcmlog"
    existing.write_bytes(b"")
    with pytest.raises(stackgen.StreamError) as error:
        sgt.StreamDataset(URL, record=existing)
    assert str(existing) in one_line(error) and "exists" in one_line(error)


# the lcm-gen Python types in the package (stackgen.msg, apart from the stream's Scene) decode
# the bytes of the recorded log as the C++ stream does
def test_python_message_types_decode_the_log():
    assert not hasattr(stackgen, "scene") and not hasattr(stackgen, "status")
    raw = [data for channel, data in log_events(TINY_LOG) if channel == "STACKGEN_SCENE"]
    streamed = list(stackgen.Stream(URL, **OPEN))
    assert len(raw) == len(streamed) == 4
    for data, scene in zip(raw, streamed):
        message = stackgen.msg.scene.decode(data)
        assert (message.header.generator_id, message.header.seq) == (scene.generator_id, scene.seq)
        assert message.camera.width == scene.width
        assert [i.instance_id for i in message.instances] == scene.instance_ids.tolist()
        assert [i.visib_fract for i in message.instances] == scene.visib_fract.tolist()
        assert message.encode() == scene.encoded() == data


# a scene whose PNG does not decode (cut short) is skipped and counted, the scenes around it
# are handed out in order
def test_scene_that_does_not_decode_is_skipped(tmp_path, capfd):
    raw = [data for channel, data in log_events(TINY_LOG) if channel == "STACKGEN_SCENE"]
    broken = stackgen.msg.scene.decode(raw[1])
    broken.color.data = broken.color.data[:len(broken.color.data) // 2]
    broken.color.size = len(broken.color.data)
    log = tmp_path / "broken.lcmlog"
    appender = stackgen._native.LogAppender(str(log))
    for data in (raw[0], broken.encode(), raw[2]):
        appender.append("STACKGEN_SCENE", data, 0)
    with stackgen.Stream("file://%s" % log) as stream:
        seqs = [scene.seq for scene in stream]
        counters = stream.counters
    assert seqs == [0, 2]
    assert counters["bad_messages"] == 1 and counters["handed"] == 2
    assert "scene 2/1: color does not decode" in capfd.readouterr().err
    # with a count, the scene that did not decode makes room for the next one
    with stackgen.Stream("file://%s" % log, count=2) as stream:
        assert [scene.seq for scene in stream] == [0, 2]
