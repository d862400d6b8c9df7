"""stackgen for learners: scenes from the bus, or from a recorded LCM log, as numpy arrays.

    import stackgen
    with stackgen.Stream(lcm_url="udpm://239.255.76.67:7667?ttl=0", reliable=True) as stream:
        for scene in stream:
            scene.rgb              # (H, W, 3) uint8, or scene.gray (H, W) for a gray camera
            scene.depth_mm         # (H, W) float32 millimetres, 0 = no depth
            scene.depth_sensor_mm  # the 3D camera's depth (config sensor_3d), with its holes
            scene.instance_map     # (H, W) uint16, 0 = background, else the instance_id
            scene.masks_visib()    # (N, H, W) uint8 0/1 visible masks, decoded on demand
            scene.camera_from_object, scene.bbox_visib, scene.visib_fract, scene.K, ...

`stackgen.torch.StreamDataset` turns the stream into (image, target) pairs for torchvision's
detection models, with exact augmentation (`stackgen.augment`); `stackgen.metrics` and
`stackgen.torch.evaluate` score models; `stackgen.coco` reads labelled folders. The LCM message
types of the bus (made by lcm-gen) are in `stackgen.msg`, for users who bring their own LCM:
`stackgen.msg.scene.decode(data)`, `stackgen.msg.status`, ...

The stream runs in C++ (`stackgen._native`): the same bounded decoding, credits and resend as
the C++ dataset writers, in a thread of its own, outside the GIL.
"""

from __future__ import annotations

import os as _os
from typing import Any as _Any, Dict as _Dict, Iterator as _Iterator, List as _List
from typing import Optional as _Optional, Sequence as _Sequence, Tuple as _Tuple

import numpy as _np

from . import _native, msg  # noqa: F401 (msg: the LCM message types, stackgen.msg.scene, ...)
from ._native import (DEFAULT_LCM_URL, StreamError, StreamTimeout, decode_rle, resolve_lcm_url,
                      set_program_name)

SCENE_CHANNEL = "STACKGEN_SCENE"
STATUS_CHANNEL = "STACKGEN_STATUS"

# the scenes a Stream hands out: the C++ class, with a few conveniences added here
Scene = _native.Scene


def _rgb(scene):
    return None if scene.is_gray else scene.color


def _gray(scene):
    return scene.color if scene.is_gray else None


def _depth_mm(scene):
    return scene.depth.astype(_np.float32) * _np.float32(scene.depth_scale_mm)


def _depth_sensor_mm(scene):
    if not scene.has_depth_sensor:
        return None
    return scene.depth_sensor.astype(_np.float32) * _np.float32(scene.depth_scale_mm)


def _point_cloud(scene, sensor: bool = True):
    """(H, W, 3) float32 points in the camera frame (OpenCV: x right, y down, z forward), mm,
    NaN where there is no depth: an organised cloud of the 3D camera's depth (`sensor`, where the
    scene has one) or of the exact depth."""
    depth = scene.depth_sensor_mm if sensor and scene.has_depth_sensor else scene.depth_mm
    K = scene.K
    v, u = _np.mgrid[0:depth.shape[0], 0:depth.shape[1]].astype(_np.float32)
    z = _np.where(depth > 0, depth, _np.float32(_np.nan))
    x = (u - _np.float32(K[0, 2])) * z / _np.float32(K[0, 0])
    y = (v - _np.float32(K[1, 2])) * z / _np.float32(K[1, 1])
    return _np.stack([x, y, z], axis=-1)


def _instances(scene):
    return [Instance(scene, k) for k in range(scene.num_instances)]


def _scene_repr(scene):
    return "<stackgen.Scene generator %d seq %d: %dx%d, %d instances>" % (
        scene.generator_id, scene.seq, scene.width, scene.height, scene.num_instances)


Scene.rgb = property(_rgb, doc="(H, W, 3) uint8 RGB image, None for a gray camera (no copy).")
Scene.gray = property(_gray, doc="(H, W) uint8 gray image, None for a colour camera (no copy).")
Scene.depth_mm = property(
    _depth_mm, doc="(H, W) float32 depth along the camera z axis in millimetres, 0 = no depth "
                   "(`depth` is the stored uint16, mm = value * depth_scale_mm).")
Scene.depth_sensor_mm = property(
    _depth_sensor_mm, doc="(H, W) float32 depth as the config's 3D camera measures it (sensor_3d), "
                          "mm, 0 = no depth (its shadow, dropout); None without a 3D camera.")
Scene.point_cloud = _point_cloud
Scene.instances = property(_instances, doc="One `Instance` per labelled object of the scene.")
Scene.__repr__ = _scene_repr


class Instance:
    """One object instance of a scene.

    A view: the values come from the scene's arrays. `Scene.instances` makes one per labelled
    object.

    Args:
        scene: the scene that holds the instance.
        index: the instance's index in the scene's per-instance arrays.
    """

    def __init__(self, scene, index):
        self._scene = scene
        self.index = index
        self.instance_id = int(scene.instance_ids[index])
        self.class_id = int(scene.class_ids[index])
        self.class_name = scene.class_names[index]
        self.bbox_obj = scene.bbox_obj[index]
        self.bbox_visib = scene.bbox_visib[index]
        self.camera_from_object = scene.camera_from_object[index]
        self.world_from_object = scene.world_from_object[index]
        self.posture_deg = scene.posture_deg[index]
        self.resting_face = int(scene.resting_face[index])
        self.px_count_all = int(scene.px_count_all[index])
        self.px_count_visib = int(scene.px_count_visib[index])
        self.visib_fract = float(scene.visib_fract[index])
        self.annotated = bool(scene.annotated[index])
        self.ignored = bool(scene.ignored[index])

    def mask_visib(self) -> _np.ndarray:
        """The visible mask of the instance, decoded from the message's RLE.

        Returns:
            (H, W) uint8 0/1: the visible pixels.
        """
        return self._scene.masks_visib([self.index])[0]

    def mask_obj(self) -> _np.ndarray:
        """The full (amodal) mask of the instance.

        Returns:
            (H, W) uint8 0/1: the pixels the object would cover with nothing in front.
        """
        return self._scene.masks_obj([self.index])[0]

    def __repr__(self):
        return "<stackgen.Instance %d (%s) visib_fract %.3f%s>" % (
            self.instance_id, self.class_name, self.visib_fract,
            " annotated" if self.annotated else " ignored" if self.ignored else "")


def _check_int(name, value, low, high):
    if isinstance(value, bool) or not isinstance(value, (int, _np.integer)) or \
            not low <= value <= high:
        raise ValueError("%s must be a whole number in %d..%d, got %r" % (name, low, high, value))
    return int(value)


class Stream:
    """Scenes from a generator bus or an LCM log, one at a time.

    Iterate over the stream, or call `next`, to take the scenes. A scene that fails its checks
    (sizes, images, masks, ids) is skipped and counted in `counters["bad_messages"]`, with a
    line on stderr for the first ten.

    Args:
        lcm_url: the bus (udpm://..., memq://) or a log, file://PATH (any ?query is ignored: a
            log is read in file order, as fast as scenes are taken). None: $STACKGEN_LCM_URL,
            else stackgen.DEFAULT_LCM_URL.
        reliable: on a live bus, a reliable consumer: it credits each scene once it has been
            handed out and asks for the ones it missed, so it misses nothing and holds
            generators within `window` scenes of what it took; it stores nothing on disk. It
            takes a generator from seq 0 when it first hears it within its first `window` seqs
            (they started together), else from the first scene it hears (it joins a running
            generator without making it resend its history). False: best effort: it sends
            nothing, never holds a generator back, and keeps only the newest `queue` scenes when
            the caller falls behind.
        window: reliable: scenes a generator may run ahead of what was handed out (1..10000).
        generator_ids: take scenes of these generators only (default: all).
        timeout: seconds to wait for a scene before StreamTimeout is raised (naming the
            generators heard); None: wait as long as it takes. A waiting stream says what it
            waits for on stderr after 2 s and every 30 s.
        count: end after this many scenes (0: no end; a log ends at its end). A live stream
            also ends once every generator it takes from has ended its run or stopped (their
            last status says so), with a line on stderr: iterating ends, `next` returns None.
        shard: (index, count): take only the seqs with seq % count == index, so several streams
            (DataLoader workers) split one bus or log between them without sharing a scene.
        queue: scenes kept waiting for the caller (best effort drops older ones; a log waits).
        instance_map: decode the instance map ahead, beside the colour image (default yes);
            images not decoded ahead are decoded when first asked for.
        depth: decode the depth image ahead, beside the colour image (default no).
        repeats: a log only: hand out repeated events too, with `scene.occurrence` counting
            them (StreamDataset recordings repeat a scene for each use); False: each scene once.
        decode_threads: threads that decode images ahead while scenes wait in the queue (1..16,
            default 2); scenes are handed out in their order all the same.
        channel: the scenes' channel.
        name: the consumer's name in credits and status (default
            "stackgen-feed@<host>:<pid>").
        fault_drop: drop this fraction of received messages on purpose, [0, 1) (tests, demos).
        status: publish the stream's counters on STACKGEN_STATUS every second (live bus).
        bus_key_file: the bus key (see docs/operations.md, "Trust: the bus key"): scenes not signed with it are
            refused and counted (counters "refused_unsigned", "refused_forged",
            "refused_replayed", "refused_relayed"), and credits are signed; a log is checked with it too. None:
            $STACKGEN_BUS_KEY_FILE when set, else this user's key ~/.config/stackgen/bus.key
            (made on first use), as every stackgen program does.
        open_bus: no key at all: nothing signed, every sender trusted (an open bus, or a log
            recorded on one). Excludes bus_key_file.
        replay: a live bus that carries a recording played back (lcm-logplayer): its scenes are
            taken without the liveness check that refuses recordings by default. (A file:// log
            needs no flag.)

    Raises:
        ValueError: an argument of the wrong type or out of its range, or both bus_key_file and
            open_bus=True.
        StreamError: a bus that cannot be opened (a bad URL, no multicast route), a missing
            log or one that is not an LCM log, a log event on the channel that is not a
            stackgen.scene of this build, a log without scenes, generators that use another bus
            key (heard for 2 s, none with this one) or a log whose every scene the key refuses,
            and a stream used in another process than the one that opened it (a DataLoader
            worker must open its own). The message is one line naming the URL, file or value.
    """

    def __init__(self, lcm_url: _Optional[str] = None, reliable: bool = True, window: int = 8,
                 generator_ids: _Optional[_Sequence[int]] = None,
                 timeout: _Optional[float] = None, count: int = 0,
                 shard: _Tuple[int, int] = (0, 1), queue: int = 16, instance_map: bool = True,
                 depth: bool = False, repeats: bool = False, decode_threads: int = 2,
                 channel: str = SCENE_CHANNEL, name: _Optional[str] = None,
                 fault_drop: float = 0.0, status: bool = True,
                 bus_key_file: _Optional[str] = None, open_bus: bool = False,
                 replay: bool = False) -> None:
        if lcm_url is not None and (not isinstance(lcm_url, str) or lcm_url == ""):
            raise ValueError("lcm_url must be a non-empty URL string or None, got %r" % (lcm_url,))
        if timeout is not None and not (isinstance(timeout, (int, float)) and timeout > 0):
            raise ValueError("timeout must be a number of seconds > 0 or None, got %r" % (timeout,))
        try:
            shard_index, shard_count = shard
        except (TypeError, ValueError):
            raise ValueError("shard must be (index, count), got %r" % (shard,)) from None
        shard_count = _check_int("shard count", shard_count, 1, 256)
        shard_index = _check_int("shard index", shard_index, 0, shard_count - 1)
        ids = [] if generator_ids is None else [
            _check_int("generator id", g, 0, 65535) for g in generator_ids]
        if bus_key_file is not None and (not isinstance(bus_key_file, str) or bus_key_file == ""):
            raise ValueError("bus_key_file must be a non-empty path or None, got %r" %
                             (bus_key_file,))
        if bus_key_file is not None and open_bus:
            raise ValueError("bus_key_file and open_bus=True exclude each other")
        if not isinstance(fault_drop, (int, float)) or not 0 <= fault_drop < 1:
            raise ValueError("fault_drop must be in [0, 1), got %r" % (fault_drop,))
        self.timeout = timeout
        self._native = _native.Stream(
            url=lcm_url or "", channel=channel, reliable=bool(reliable),
            window=_check_int("window", window, 1, 10000), generator_ids=ids,
            shard_index=shard_index, shard_count=shard_count,
            count=_check_int("count", count, 0, 2 ** 62),
            queue=_check_int("queue", queue, 1, 100000),
            repeats=bool(repeats), decode_instance_map=bool(instance_map),
            decode_depth=bool(depth),
            decode_threads=_check_int("decode_threads", decode_threads, 1, 16), name=name or "",
            fault_drop=float(fault_drop), publish_status=bool(status),
            bus_key_file=bus_key_file or "", open_bus=bool(open_bus), replay=bool(replay))

    def __iter__(self) -> _Iterator[Scene]:
        return self

    def __next__(self) -> Scene:
        scene = self._native.next(self.timeout)
        if scene is None:
            raise StopIteration
        return scene

    def next(self, timeout: _Optional[float] = None) -> Scene:
        """Takes the next scene.

        Args:
            timeout: seconds to wait for it (None: as long as it takes).

        Returns:
            The next scene; None once the stream has ended.

        Raises:
            StreamTimeout: the time runs out.
        """
        return self._native.next(timeout)

    def close(self) -> None:
        """Stops reading; a reliable stream tells the generators it is leaving."""
        self._native.close()

    def __enter__(self) -> "Stream":
        return self

    def __exit__(self, *exc):
        self.close()

    @property
    def counters(self) -> _Dict[str, int]:
        """dict: the stream's counters.

        Keys: received, handed, duplicates, lost, reasked, bad_messages, dropped_behind,
        fault_dropped, queued. On a live bus the delivery counts (lost, reasked, fault_dropped)
        are refreshed every 20 ms, and are final once the stream is closed.
        """
        return self._native.counters

    @property
    def url(self) -> str:
        """str: the URL the stream reads (lcm_url, else $STACKGEN_LCM_URL, else the default)."""
        return self._native.url

    @property
    def name(self) -> str:
        """str: the consumer's name in credits and status."""
        return self._native.name

    @property
    def is_log(self) -> bool:
        """bool: whether the stream reads a file:// log rather than a live bus."""
        return self._native.is_log


class StatusMonitor:
    """The latest STACKGEN_STATUS of every process on a bus, heard in a thread of its own.

    A generator's status holds rate_hz, scenes, held_back_s, ... The monitor sends nothing but
    the liveness check of the bus key.

    Args:
        lcm_url: the bus, as for Stream (None: $STACKGEN_LCM_URL, else
            stackgen.DEFAULT_LCM_URL).
        bus_key_file: the bus key, as for Stream.
        open_bus: no key at all, as for Stream. Excludes bus_key_file.

    Raises:
        ValueError: both bus_key_file and open_bus=True.
    """

    def __init__(self, lcm_url: _Optional[str] = None, bus_key_file: _Optional[str] = None,
                 open_bus: bool = False) -> None:
        if bus_key_file is not None and open_bus:
            raise ValueError("bus_key_file and open_bus=True exclude each other")
        self._native = _native.StatusMonitor(lcm_url or "", bus_key_file or "", bool(open_bus))

    def latest(self, process: _Optional[str] = None) -> _List[_Dict[str, _Any]]:
        """The latest status of each process heard.

        Args:
            process: when given, only the processes of this name, e.g. "stackgen" for
                generators.

        Returns:
            A list of status dicts, one per process heard. Keys: process, name, generator_id,
            next_seq (a generator's next seq; -1 for consumers), scenes_held (a consumer's
            scenes; -1 for generators), utime, scenes, rate_hz, received, lost, resent,
            regenerated, reliable_consumers, held_back_s, run_state (0 running, 1 ended, 2
            stopped before its end; a consumer says 1 or 2 in its last status, as it leaves).
        """
        return [s for s in self._native.latest() if process is None or s["process"] == process]


class LearnerStatus:
    """A learner's progress on the bus (STACKGEN_LEARNER), for stackgen-monitor's page and
    /metrics: steps, loss, scenes taken and per second, reuse.

    Reports are kept and published from a thread of its own about once a second (report() is
    cheap: call it every step); close() publishes the last one with how the run ended. A context
    manager: leaving it closes as ended, or as stopped on an exception.

        with stackgen.LearnerStatus(URL, name="my-run") as status:
            for step in range(steps):
                ...
                status.report(step + 1, loss.item(), scenes_taken=n, target_steps=steps)

    Args:
        lcm_url: the bus, as for Stream (None: $STACKGEN_LCM_URL, else stackgen.DEFAULT_LCM_URL).
        name: the learner's name on the page (default "<process>/<host>:<pid>").
        process: the program's name (default "learner").
        bus_key_file, open_bus: the bus key, as for Stream.
    """

    def __init__(self, lcm_url: _Optional[str] = None, name: _Optional[str] = None,
                 process: str = "learner", bus_key_file: _Optional[str] = None,
                 open_bus: bool = False) -> None:
        if bus_key_file is not None and open_bus:
            raise ValueError("bus_key_file and open_bus=True exclude each other")
        import socket
        name = name or "%s/%s:%d" % (process, socket.gethostname(), _os.getpid())
        self._native = _native.LearnerPublisher(lcm_url or "", bus_key_file or "",
                                                bool(open_bus), process, name)
        self._started = None
        self._closed = False

    def report(self, steps: int, loss: float, scenes_taken: int = 0, target_steps: int = 0,
               samples: _Optional[int] = None) -> None:
        """Keeps the learner's latest progress: `steps` taken, the last `loss`, `scenes_taken`
        from the stream so far, `target_steps` in all (0: unknown), and `samples` trained on so
        far (the reuse is samples per scene; None: one per scene)."""
        import time
        now = time.monotonic()
        if self._started is None:
            self._started = now
        rate = scenes_taken / (now - self._started) if now > self._started else 0.0
        reuse = (samples / scenes_taken) if samples is not None and scenes_taken > 0 else 1.0
        self._native.report(int(steps), int(target_steps), float(loss), int(scenes_taken),
                            float(rate), float(reuse))

    def close(self, ended: bool = True) -> None:
        """Publishes the last report with the run's end (ended, or stopped before it) and stops."""
        if not self._closed:
            self._closed = True
            self._native.close(bool(ended))

    def __enter__(self) -> "LearnerStatus":
        return self

    def __exit__(self, kind, value, traceback) -> None:
        self.close(ended=kind is None)


class LogRecorder:
    """Appends scenes to an LCM log that several processes may share.

    One write per event, O_APPEND. The log is what `Stream(lcm_url="file://PATH", repeats=True)`
    reads back in the same order, and what stackgen-coco, stackgen-stats and tools/spy read.
    Each event is signed with the bus key, so the log is read back with the same key.

    Args:
        path: the log file.
        channel: the channel of the events (default STACKGEN_SCENE).
        bus_key_file: the bus key, as for Stream.
        open_bus: no key at all, as for Stream. Excludes bus_key_file.

    Raises:
        ValueError: both bus_key_file and open_bus=True.
    """

    def __init__(self, path: str, channel: str = SCENE_CHANNEL,
                 bus_key_file: _Optional[str] = None, open_bus: bool = False) -> None:
        if bus_key_file is not None and open_bus:
            raise ValueError("bus_key_file and open_bus=True exclude each other")
        self._native = _native.LogAppender(_os.fspath(path), bus_key_file or "", bool(open_bus))
        self.channel = channel

    def append(self, scene: Scene, utime: _Optional[int] = None) -> None:
        """Appends one scene to the log as one event.

        Args:
            scene: the scene, written as its encoded message.
            utime: the event's timestamp in microseconds; None: now.
        """
        import time
        self._native.append(self.channel, scene.encoded(),
                            int(time.time() * 1e6) if utime is None else int(utime))


__all__ = ["msg", "Stream", "Scene", "Instance", "StatusMonitor", "LearnerStatus", "LogRecorder",
           "StreamError", "StreamTimeout", "decode_rle", "resolve_lcm_url", "set_program_name", "DEFAULT_LCM_URL",
           "SCENE_CHANNEL", "STATUS_CHANNEL"]
