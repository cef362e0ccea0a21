"""A shared relocalization sequence written as a robot records it: a rosbag2 with its scans, its
odometry, its IMU and the true poses, each message stamped and logged as a real robot's are.

The replay tests and the benchmark of odometry's order (lab/replay_orders.py) build their
recordings here, from the shared sequences (maps/, revisit/, xseason/: consecutive scans, their
odometry and ground truth). What a robot's recording varies is a parameter: odometry logged
before, with or after its scan (a lidar-inertial odometry publishes a scan's pose after it has
processed the scan, with the scan's stamp), at the scan rate or faster (wheel odometry), with a gap
or stopping; an IMU at its own rate that reports no orientation (most LiDARs' built-in ones), its
up tilted by a stated error.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from ..core import to_matrix
from .datasets import MAP_UP

ODOMETRY_ORDERS = ("before", "with", "after")
SCAN_PERIOD_S = 0.1     # scans' spacing when the sequence gives no stamps (a 10 Hz LiDAR)
GRAVITY = 9.81


@dataclass(frozen=True)
class RecordedSequence:
    """Consecutive scans of one sequence: their stamps [s], points (sensor frame), odometry poses
    T_odom_scan and true poses T_map_scan."""

    stamps: np.ndarray
    scans: list[np.ndarray]
    odometry: np.ndarray     # (K, 4, 4)
    truth: np.ndarray        # (K, 4, 4)

    def __len__(self) -> int:
        return len(self.stamps)

    def part(self, first: int, count: int) -> RecordedSequence:
        chosen = slice(first, first + count)
        return RecordedSequence(self.stamps[chosen], self.scans[chosen], self.odometry[chosen], self.truth[chosen])


def load_recorded_sequence(folder: Path) -> RecordedSequence:
    """The scans of ``folder``'s scans/ in index order with their odometry (odometry.txt) and their
    true poses: the odometry carried into the map by the first query's ground truth. Stamps are the
    queries' own where queries.json gives them, interpolated by index between them, else the
    scan's index at 10 Hz."""
    folder = Path(folder)
    rows = np.loadtxt(folder / "odometry.txt", comments="#", ndmin=2)
    indices = rows[:, 0].astype(int)
    odometry = np.array([to_matrix(Rotation.from_quat(r[4:8]).as_matrix(), r[1:4]) for r in rows])
    queries = [{**q, "index": q.get("source_index", q.get("source_indices", [None])[0])}
               for q in json.loads((folder / "queries.json").read_text()) if q.get("kind", "scan") == "scan"]
    queries = [q for q in queries if q["index"] in set(indices.tolist())]
    anchor = queries[0]
    k = int(np.flatnonzero(indices == anchor["index"])[0])
    T_map_odom = np.loadtxt(folder / "queries" / anchor["id"] / "gt.txt") @ np.linalg.inv(odometry[k])
    known = [(q["index"], q["stamp"]) for q in queries if "stamp" in q]
    if len(known) >= 2:
        at, stamps = np.array(known, dtype=float).T
        slope = (stamps[-1] - stamps[0]) / (at[-1] - at[0])
        stamps = np.interp(indices, at, stamps, left=np.nan, right=np.nan)
        stamps = np.where(np.isnan(stamps), known[0][1] + slope * (indices - known[0][0]), stamps)
    else:
        stamps = 100.0 + SCAN_PERIOD_S * indices
    scans = [np.load(folder / "scans" / f"{i:06d}.npy") for i in indices]
    return RecordedSequence(stamps, scans, odometry, T_map_odom @ odometry)


def interpolated(stamps: np.ndarray, poses: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Poses at ``at`` (inside stamps' span): positions linearly, rotations by slerp."""
    rotations = Slerp(stamps, Rotation.from_matrix(poses[:, :3, :3]))(at).as_matrix()
    positions = np.column_stack([np.interp(at, stamps, poses[:, i, 3]) for i in range(3)])
    return np.array([to_matrix(R, t) for R, t in zip(rotations, positions, strict=True)])


@dataclass(frozen=True)
class Recording:
    """How the robot's messages are stamped and logged."""

    odometry: str | None = "after"   # ODOMETRY_ORDERS, or None for no odometry
    odometry_rate: float = 0.0       # Hz; 0: one message a scan, at its stamp (a LIO's)
    odometry_lag: float = 0.03       # s between a scan (or an odometry stamp) and when odometry is logged
    odometry_gap: tuple[float, float] | None = None   # no odometry stamped in [from, to) [s after the first scan]
    odometry_stops: float | None = None               # no odometry stamped after this [s after the first scan]
    imu_rate: float = 0.0            # Hz; 0: no IMU
    imu_tilt_deg: float = 0.0        # the IMU's up off the truth's by this, its direction drawn at each scan
    tracked_shift: tuple[float, ...] | None = None    # a localization stack's pose on /amcl_pose at each scan:
    # the truth moved this far along x [m]; None: no such topic
    cloud_fields: str = "xyz"        # the scans' PointCloud2 fields (three float32)
    seed: int = 0


def write_recording(path: Path, sequence: RecordedSequence, recording: Recording, storage: str = "mcap") -> Path:
    """``sequence`` as a rosbag2 at ``path``: /points (PointCloud2, frame 'lidar'), /odom
    (nav_msgs/Odometry, 'odom' -> 'lidar'), /imu (sensor_msgs/Imu in the lidar frame, no
    orientation), /truth (PoseStamped in 'map') and /amcl_pose (PoseWithCovarianceStamped in
    'map'), each logged as ``recording`` says."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore
    store = get_typestore(Stores.ROS2_JAZZY)
    messages = _messages(store, sequence, recording)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        types = {"/points": "sensor_msgs/msg/PointCloud2", "/odom": "nav_msgs/msg/Odometry",
                 "/imu": "sensor_msgs/msg/Imu", "/truth": "geometry_msgs/msg/PoseStamped",
                 "/amcl_pose": "geometry_msgs/msg/PoseWithCovarianceStamped"}
        used = {topic for _, topic, _ in messages}
        connections = {topic: writer.add_connection(topic, msgtype, typestore=store)
                       for topic, msgtype in types.items() if topic in used}
        for logged, topic, message in sorted(messages, key=lambda m: m[0]):
            writer.write(connections[topic], int(round(logged * 1e9)),
                         store.serialize_cdr(message, message.__msgtype__))  # type: ignore[attr-defined]
    return path


def _messages(store, sequence: RecordedSequence, recording: Recording) -> list[tuple[float, str, object]]:
    """(log time, topic, message) of every message."""
    t = store.types
    start = float(sequence.stamps[0])
    out: list[tuple[float, str, object]] = []
    for k, (stamp, points, truth) in enumerate(zip(sequence.stamps, sequence.scans, sequence.truth, strict=True)):
        out.append((stamp, "/points", _cloud(store, points, stamp, recording.cloud_fields)))
        out.append((stamp, "/truth", t["geometry_msgs/msg/PoseStamped"](header=_header(store, stamp, "map"),
                                                                         pose=_pose(store, truth))))
        if recording.tracked_shift is not None:
            stack = truth.copy()
            stack[0, 3] += recording.tracked_shift[k]
            out.append((stamp, "/amcl_pose", t["geometry_msgs/msg/PoseWithCovarianceStamped"](
                header=_header(store, stamp, "map"),
                pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=_pose(store, stack), covariance=np.zeros(36)))))
    if recording.odometry is not None:
        if recording.odometry_rate > 0:
            stamps = np.arange(start, sequence.stamps[-1], 1.0 / recording.odometry_rate)
            poses = interpolated(sequence.stamps, sequence.odometry, stamps)
        else:
            stamps, poses = sequence.stamps, sequence.odometry
        shift = {"before": -recording.odometry_lag, "with": 0.0, "after": recording.odometry_lag}[recording.odometry]
        for stamp, pose in zip(stamps, poses, strict=True):
            since = stamp - start
            if recording.odometry_gap and recording.odometry_gap[0] <= since < recording.odometry_gap[1]:
                continue
            if recording.odometry_stops is not None and since > recording.odometry_stops:
                continue
            out.append((stamp + shift, "/odom", _odometry(store, pose, stamp)))
    if recording.imu_rate > 0:
        out += [(stamp, "/imu", message) for stamp, message in _imu(store, sequence, recording)]
    return out


def _imu(store, sequence: RecordedSequence, recording: Recording):
    """An IMU in the scan frame that reports no orientation, as most LiDARs' built-in ones: its
    acceleration is gravity's reaction along the truth's up (the truth's orientation interpolated
    between the scans), tilted by imu_tilt_deg about an axis drawn for each scan and turned smoothly
    from one scan's to the next (a drifting bias); its angular velocity is the truth's turn rate."""
    rng = np.random.default_rng(recording.seed)
    period = 1.0 / recording.imu_rate
    stamps = np.arange(sequence.stamps[0] - 1.0, sequence.stamps[-1] + period / 2, period)
    inside = np.clip(stamps, sequence.stamps[0], sequence.stamps[-1])
    body = Slerp(sequence.stamps, Rotation.from_matrix(sequence.truth[:, :3, :3]))(inside)
    axes = rng.normal(size=(len(sequence), 3))
    tilts = Rotation.from_rotvec(np.radians(recording.imu_tilt_deg) * axes / np.linalg.norm(axes, axis=1)[:, None])
    tilt = Slerp(sequence.stamps, tilts)(inside) if len(sequence) > 1 else Rotation.concatenate([tilts] * len(stamps))
    up = tilt.apply(body.inv().apply(MAP_UP))
    turn = (body[:-1].inv() * body[1:]).as_rotvec() / period            # body frame, from one reading to the next
    gyro = np.vstack([turn, turn[-1:]])
    Imu, Vector3, Quaternion = (store.types[f"{n}"] for n in ("sensor_msgs/msg/Imu", "geometry_msgs/msg/Vector3",
                                                               "geometry_msgs/msg/Quaternion"))
    unknown = np.zeros(9)
    unknown[0] = -1.0   # REP 145: no orientation reported
    for stamp, a, w in zip(stamps, GRAVITY * up, gyro, strict=True):
        yield stamp, Imu(header=_header(store, stamp, "lidar"), orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
                         orientation_covariance=unknown, angular_velocity=Vector3(x=w[0], y=w[1], z=w[2]),
                         angular_velocity_covariance=np.zeros(9),
                         linear_acceleration=Vector3(x=a[0], y=a[1], z=a[2]),
                         linear_acceleration_covariance=np.zeros(9))


def _header(store, seconds: float, frame: str):
    Header, Time = store.types["std_msgs/msg/Header"], store.types["builtin_interfaces/msg/Time"]
    nanoseconds = int(round(seconds * 1e9))
    return Header(stamp=Time(sec=nanoseconds // 10**9, nanosec=nanoseconds % 10**9), frame_id=frame)


def _cloud(store, points: np.ndarray, seconds: float, fields: str = "xyz"):
    PointCloud2, PointField = store.types["sensor_msgs/msg/PointCloud2"], store.types["sensor_msgs/msg/PointField"]
    data = np.ascontiguousarray(points, dtype="<f4")
    layout = [PointField(name=name, offset=4 * i, datatype=7, count=1) for i, name in enumerate(fields)]
    return PointCloud2(header=_header(store, seconds, "lidar"), height=1, width=len(data), fields=layout,
                       is_bigendian=False, point_step=12, row_step=12 * len(data),
                       data=data.view(np.uint8).reshape(-1), is_dense=True)


def _pose(store, T: np.ndarray):
    Pose, Point, Quaternion = (store.types[f"geometry_msgs/msg/{n}"] for n in ("Pose", "Point", "Quaternion"))
    x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
    return Pose(position=Point(x=T[0, 3], y=T[1, 3], z=T[2, 3]), orientation=Quaternion(x=x, y=y, z=z, w=w))


def _odometry(store, T: np.ndarray, seconds: float):
    t = store.types
    Twist, Vector3 = t["geometry_msgs/msg/Twist"], t["geometry_msgs/msg/Vector3"]
    still = t["geometry_msgs/msg/TwistWithCovariance"](
        twist=Twist(linear=Vector3(x=0.0, y=0.0, z=0.0), angular=Vector3(x=0.0, y=0.0, z=0.0)), covariance=np.zeros(36))
    return t["nav_msgs/msg/Odometry"](header=_header(store, seconds, "odom"), child_frame_id="lidar",
                                      pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=_pose(store, T),
                                                                                     covariance=np.zeros(36)),
                                      twist=still)
