"""Builders of the node's output messages from a RegistrationResult."""
from __future__ import annotations

import json
from typing import TYPE_CHECKING

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Pose, PoseArray, PoseStamped, PoseWithCovarianceStamped
from sensor_msgs.msg import Imu
from std_msgs.msg import ColorRGBA, Header, String
from visualization_msgs.msg import Marker, MarkerArray

from ..core import to_matrix, transform_points

if TYPE_CHECKING:   # the pipeline's load is not needed to build messages from its results
    from ..core import RegistrationResult

INLIER_COLOUR = ColorRGBA(r=0.1, g=0.9, b=0.2, a=1.0)
OUTLIER_COLOUR = ColorRGBA(r=0.9, g=0.1, b=0.1, a=0.6)


def pose_from_matrix(T: np.ndarray) -> Pose:
    from scipy.spatial.transform import Rotation  # scipy.spatial loads slowly: not for a client's --help
    pose = Pose()
    pose.position.x, pose.position.y, pose.position.z = (float(v) for v in T[:3, 3])
    x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
    pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w = (
        float(x), float(y), float(z), float(w))
    return pose


def matrix_from_pose(pose: Pose) -> np.ndarray:
    """The 4x4 transform of a geometry_msgs/Pose (the inverse of pose_from_matrix)."""
    from scipy.spatial.transform import Rotation
    p, q = pose.position, pose.orientation
    return to_matrix(Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix(), np.array([p.x, p.y, p.z]))


def stamp_seconds(header: Header) -> float:
    return header.stamp.sec + 1e-9 * header.stamp.nanosec


def stamp_nanoseconds(header) -> int:
    """The header's stamp as one exact integer (a ROS header, or a rosbags one)."""
    return header.stamp.sec * 10**9 + header.stamp.nanosec


def header_at(stamp_ns: int, frame_id: str) -> Header:
    """A header with the exact stamp of an input (stamp_nanoseconds) and ``frame_id``."""
    return Header(stamp=Time(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9), frame_id=frame_id)


def imu_reading(msg: Imu) -> tuple:
    """(stamp, orientation xyzw or None, linear acceleration, angular velocity or None): REP 145, a
    covariance[0] of -1 says the field is not reported."""
    q, a, w = msg.orientation, msg.linear_acceleration, msg.angular_velocity
    orientation = None if msg.orientation_covariance[0] == -1.0 else np.array([q.x, q.y, q.z, q.w])
    gyro = None if msg.angular_velocity_covariance[0] == -1.0 else np.array([w.x, w.y, w.z])
    return stamp_seconds(msg.header), orientation, np.array([a.x, a.y, a.z]), gyro


def pose_key(msg: PoseWithCovarianceStamped) -> tuple:
    """A pose message's identity (stamp, frame, position), to recognise one of the node's own
    poses come back as a hint."""
    p = msg.pose.pose.position
    return (msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id,
            round(p.x, 6), round(p.y, 6), round(p.z, 6))


def pose_stamped(T: np.ndarray, header: Header) -> PoseStamped:
    return PoseStamped(header=header, pose=pose_from_matrix(T))


def pose_with_covariance(T: np.ndarray, covariance: np.ndarray, header: Header) -> PoseWithCovarianceStamped:
    msg = PoseWithCovarianceStamped(header=header)
    msg.pose.pose = pose_from_matrix(T)
    msg.pose.covariance = [float(v) for v in covariance.reshape(-1)]
    return msg


def candidate_poses(result: RegistrationResult, header: Header, limit: int, T_sensor_frame=None) -> PoseArray:
    """The search's distinct candidate poses, best supported first (at most ``limit``), each of
    the frame ``T_sensor_frame`` places relative to the sensor (the base, for Nav2) when given."""
    poses = [c.transform for c in result.candidates[:limit]]
    if T_sensor_frame is not None:
        poses = [T @ T_sensor_frame for T in poses]
    return PoseArray(header=header, poses=[pose_from_matrix(T) for T in poses])


def _line_marker(header: Header, ident: int, name: str, colour: ColorRGBA,
                 start: np.ndarray, end: np.ndarray, width: float) -> Marker:
    marker = Marker(header=header, ns=name, id=ident, type=Marker.LINE_LIST, action=Marker.ADD)
    marker.pose.orientation.w = 1.0
    marker.scale.x = width
    marker.color = colour
    ends = np.empty((2 * len(start), 3))
    ends[0::2], ends[1::2] = start, end
    marker.points = [Point(x=float(x), y=float(y), z=float(z)) for x, y, z in ends]
    return marker


def correspondence_markers(result: RegistrationResult, header: Header, max_lines: int,
                           line_width: float) -> MarkerArray:
    """Initial feature matches as line lists in the target frame, from each source keypoint placed
    by the estimated pose to its matched target keypoint: inliers green (short by construction),
    outliers red. At most ``max_lines`` lines, inliers first; the previous set is deleted."""
    clear = Marker(header=header, action=Marker.DELETEALL)
    inlier = result.initial.inlier
    start = transform_points(result.transform, result.initial.source)
    end = result.initial.target
    n_in = min(int(inlier.sum()), max_lines)
    n_out = min(int((~inlier).sum()), max_lines - n_in)
    markers = [clear]
    for ident, (name, colour, mask, count) in enumerate(
            [("inliers", INLIER_COLOUR, inlier, n_in), ("outliers", OUTLIER_COLOUR, ~inlier, n_out)]):
        if count:
            index = np.flatnonzero(mask)[:count]
            markers.append(_line_marker(header, ident, name, colour, start[index], end[index],
                                        line_width))
    return MarkerArray(markers=markers)


def status_message(result: RegistrationResult, extra: dict) -> String:
    """Quality figures, stage sizes and timings as JSON, for logs and dashboards."""
    return String(data=json.dumps({**result.summary().as_json(), **extra}))
