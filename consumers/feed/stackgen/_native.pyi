"""Types of stackgen._native, the C++ half of the package (consumers/feed/python_module.cc).

Use the names `stackgen` exports; these are for type checkers and editors. test_native_stub.py
checks that this file and the module name the same things.
"""

from typing import Any, Dict, List, Optional, Sequence

import numpy as np
import numpy.typing as npt

DEFAULT_LCM_URL: str


class StreamError(RuntimeError):
    """The stream cannot go on: a bad URL, key or log, or a generator of another run."""


class StreamTimeout(StreamError, TimeoutError):
    """No scene within the timeout."""


class Scene:
    """One scene as a stream hands it out: labels and images, numpy views without copies."""

    generator_id: int
    seq: int
    seed: int
    utime: int
    occurrence: int
    width: int
    height: int
    K: npt.NDArray[np.float64]                   # (3, 3)
    world_from_camera: npt.NDArray[np.float64]   # (4, 4), mm
    depth_scale_mm: float
    is_gray: bool
    has_depth: bool
    has_depth_sensor: bool                       # a 3D camera's depth (config sensor_3d)
    color: npt.NDArray[np.uint8]                 # (H, W, 3) RGB or (H, W) gray
    depth: npt.NDArray[np.uint16]                # (H, W), mm = value x depth_scale_mm
    instance_map: npt.NDArray[np.uint16]         # (H, W), 0 = background
    depth_sensor: npt.NDArray[np.uint16]         # (H, W), the 3D camera's, 0 = no depth
    num_instances: int
    instance_ids: npt.NDArray[np.int32]
    class_ids: npt.NDArray[np.int32]
    class_names: List[str]
    camera_from_object: npt.NDArray[np.float64]  # (N, 4, 4), mm
    world_from_object: npt.NDArray[np.float64]   # (N, 4, 4), mm
    posture_deg: npt.NDArray[np.float64]         # (N, 3)
    resting_face: npt.NDArray[np.int32]
    bbox_obj: npt.NDArray[np.int32]              # (N, 4) x, y, w, h
    bbox_visib: npt.NDArray[np.int32]            # (N, 4) x, y, w, h
    px_count_all: npt.NDArray[np.int32]
    px_count_visib: npt.NDArray[np.int32]
    visib_fract: npt.NDArray[np.float64]
    annotated: npt.NDArray[np.bool_]
    # config grasps: every suction grasp, one array per field (instance_id, rank, uv (G, 2),
    # point_mm (G, 3) and normal (G, 3) in the camera frame, seal, clearance_mm,
    # approach_clear, com_offset_mm, proof (0 not tried, 1 lifted, 2 dropped, 3 stuck),
    # proof_swing_deg, proof_neighbours_moved_mm), each instance's best first
    suction_grasps: Dict[str, npt.NDArray[Any]]
    # config grasps.parallel_jaw: every parallel-jaw grasp (instance_id, rank, uv, point_a_mm,
    # point_b_mm and approach (G, 3) in the camera frame, width_mm, cone_margin_deg,
    # clearance_mm, approach_clear, com_offset_mm, proof, proof_swing_deg,
    # proof_neighbours_moved_mm)
    jaw_grasps: Dict[str, npt.NDArray[Any]]
    ignored: npt.NDArray[np.bool_]
    # added by stackgen/__init__.py
    rgb: Optional[npt.NDArray[np.uint8]]
    gray: Optional[npt.NDArray[np.uint8]]
    depth_mm: npt.NDArray[np.float32]
    depth_sensor_mm: Optional[npt.NDArray[np.float32]]
    def point_cloud(self, sensor: bool = True) -> npt.NDArray[np.float32]: ...
    instances: List[Any]                          # stackgen.Instance, one per object

    def masks_visib(self, indices: Optional[Sequence[int]] = None) -> npt.NDArray[np.uint8]: ...
    def masks_obj(self, indices: Optional[Sequence[int]] = None) -> npt.NDArray[np.uint8]: ...
    def boxed_masks_obj(self, indices: Sequence[int]) -> List[npt.NDArray[np.uint8]]: ...
    def boxed_masks_visib(self, indices: Sequence[int]) -> List[npt.NDArray[np.uint8]]: ...
    def encoded(self) -> bytes: ...


class Stream:
    """The C++ stream behind stackgen.Stream (which gives these arguments their defaults)."""

    counters: Dict[str, int]
    url: str
    name: str
    is_log: bool

    def __init__(self, url: str, channel: str, reliable: bool, window: int,
                 generator_ids: List[int], shard_index: int, shard_count: int, count: int,
                 queue: int, repeats: bool, decode_instance_map: bool, decode_depth: bool,
                 decode_threads: int, name: str, fault_drop: float, publish_status: bool,
                 bus_key_file: str = "", open_bus: bool = False, replay: bool = False) -> None: ...
    def next(self, timeout_s: Optional[float] = None) -> Scene: ...
    def close(self) -> None: ...


class LogAppender:
    """Appends events to an LCM log, signed with the bus key unless open_bus."""

    path: str

    def __init__(self, path: str, bus_key_file: str = "", open_bus: bool = False) -> None: ...
    def append(self, channel: str, data: bytes, utime: int) -> None: ...


class StatusMonitor:
    """Listens to STACKGEN_STATUS; latest() is the newest status of every process heard."""

    def __init__(self, url: str, bus_key_file: str = "", open_bus: bool = False) -> None: ...
    def latest(self) -> List[Dict[str, Any]]: ...


def decode_rle(counts: str, height: int, width: int) -> npt.NDArray[np.uint8]: ...
def resolve_lcm_url(url: str) -> str: ...
def set_program_name(name: str) -> None: ...


class LearnerPublisher:
    def __init__(self, url: str, bus_key_file: str, open_bus: bool, process: str,
                 name: str) -> None: ...
    def report(self, steps: int, target_steps: int, loss: float, scenes_taken: int,
               scenes_per_second: float, reuse: float) -> None: ...
    def close(self, ended: bool) -> None: ...
