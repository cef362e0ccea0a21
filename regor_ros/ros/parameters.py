"""ROS parameters of the node, declared from the core's RegorConfig and the node's own settings.

Every leaf of RegorConfig becomes a parameter named ``section.field`` (``features.voxel_size``)
with its description and range; ``preset`` picks the defaults they start from.
"""
from __future__ import annotations

import dataclasses
import difflib
from dataclasses import dataclass

import numpy as np
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from scipy.spatial.transform import Rotation

from ..core import CHOICES as CORE_CHOICES
from ..core import (
    ORIGIN,
    PRESETS,
    AccumulationLimits,
    ConfigError,
    RegorConfig,
    coerce,
    param,
    parse_numbers,
    parse_viewpoint,
    to_matrix,
)
from .input_qos import QOS_KINDS

MODE_CHOICES = ("pairs", "map")
REGISTRATION_CHOICES = ("continuous", "on_demand")
TRACKED_POSE_TYPES = ("pose_with_covariance", "odometry")


@dataclass
class NodeSettings:
    """What the node does around the core: inputs, modes and outputs."""

    mode: str = param("pairs", "pairs: register each new source/target pair; map: the latest target "
                       "is a map prepared once, every new source is registered against it")
    autostart: bool = param(True, "configure and activate at start, as a plain node (exit with the reason when "
                             "configure fails); false: wait in the unconfigured state for a lifecycle manager "
                             "(Nav2's lifecycle_manager) to drive it (read only)")
    registration: str = param("continuous", "continuous: register every new source; on_demand: only the next "
                               "source after a call of the relocalize service (std_srvs/Trigger)")
    relocalize_timeout: float = param(10.0, "how long a relocalize call waits for the next source and its "
                                       "registration [s]", 0.1, 3600.0)
    max_stamp_difference: float = param(0.0, "pairs mode: register only clouds whose stamps differ "
                                         "by at most this [s]; 0 = any", 0.0, 1e6)
    source_qos: str = param("auto", "QoS of source_cloud: auto (reliable when every publisher is, transient "
                             "local when every publisher is, best effort otherwise; followed as publishers "
                             "come and go), sensor_data (best effort), reliable, or transient_local (latched)")
    target_qos: str = param("auto", "QoS of target_cloud: auto, sensor_data, reliable, or transient_local "
                             "(see source_qos)")
    max_markers: int = param(500, "most correspondence lines published on correspondences", 0, 100000)
    max_candidates: int = param(5, "most poses published on candidates after every registration: the pose, then the "
                                 "other places the search found, best supported first; 0 = none", 0, 1000)
    marker_line_width: float = param(0.01, "line width of the correspondence markers [m]", 1e-4, 10.0)
    publish_aligned_cloud: bool = param(False, "publish the source cloud moved into the target frame "
                                         "on aligned_cloud")
    publish_rejected: bool = param(False, "also publish poses that fail the quality gate (status "
                                    "says so); off: a rejected pose is only reported")
    diagnostics_period: float = param(1.0, "seconds between DiagnosticArray messages on /diagnostics; 0 = none "
                                       "(read only)", 0.0, 3600.0)
    source_viewpoint: str = param("auto", "where the source sensor sat in the source message's frame, for "
                                   "the free-space check: 'x, y, z' [m], 'none' (unknown: an aggregated "
                                   "cloud), or auto (the frame's origin)")
    target_viewpoint: str = param("auto", "where the target sensor sat in the target message's frame: "
                                   "'x, y, z' [m], 'none', or auto (the frame's origin in pairs mode; none "
                                   "in map mode, a map has no single viewpoint)")

    map_file: str = param("", "map mode: the map as a file (.pcd, .ply, .npy, .xyz/.txt, KITTI .bin), loaded at "
                           "start instead of target_cloud and published once on map_cloud; '' = the map comes "
                           "on target_cloud (read only)")
    map_frame: str = param("map", "frame of the map_file's points: the frame the poses are published in (read only)")
    map_trajectory_file: str = param("", "the sensor poses the map_file was built from, TUM format (t x y z qx qy "
                                      "qz qw, as SLAM packages save it): the free-space check also sees the map "
                                      "from them, and with features.normals_toward_sensors (the outdoor preset) "
                                      "the map's normals face them, as each scan's face its sensor; '' = none: "
                                      "both keep the solver's signs (read only)")
    map_cache: bool = param(True, "keep the prepared map_file in a cache (map_cache_dir), one file for each map, "
                             "trajectory and feature settings, and load it at the next start that matches; an "
                             "unreadable cache is rebuilt, a map refused writes none (read only)")
    map_cache_dir: str = param("", "folder for the map cache; '' = $XDG_CACHE_HOME/regor_ros (~/.cache/regor_ros) "
                                "(read only)")

    initial_guess_sigmas: float = param(3.0, "an initial_guess restricts the search to this many standard "
                                             "deviations of "
                                         "its position covariance around it", 0.0, 100.0)
    initial_guess_min_radius: float = param(2.0, "the search radius of an initial_guess is at least this, however "
                                             "certain it claims to be [m]", 0.0, 1e5)
    initial_guess_max_radius: float = param(50.0, "the search radius of an initial_guess is at most this, however "
                                             "uncertain it is [m]", 0.0, 1e6)

    accumulate_scans: int = param(0, "scans fused along odometry into one source, the newest included: 1 = "
                                   "each scan alone; 0 = auto (1 in pairs mode, 5 in map mode: a sparse scan "
                                   "often has too few correct matches to be found in a map; needs odometry)", 0, 100)
    accumulate_max_distance: float = param(10.0, "fuse only scans whose sensor was within this of the newest "
                                            "one's (odometry drifts with distance) [m]", 0.0, 1e4)
    accumulate_max_age: float = param(10.0, "fuse only scans at most this much older than the newest [s]", 0.0, 1e4)
    odometry_tolerance: float = param(0.05, "a scan is placed by the odometry interpolated around its stamp, or "
                                       "the nearest message within this; a scan with none is not fused [s]", 0.0, 10.0)
    odometry_wait: float = param(0.3, "a scan to be fused waits at most this for odometry at or after its stamp "
                                  "before it is registered with what has arrived (a lidar-inertial odometry "
                                  "publishes a scan's pose after it has processed the scan); the worker never "
                                  "idles longer, however many scans replace the waiting one [s]; 0 = no wait",
                                  0.0, 10.0)
    odometry_to_scan: str = param("0, 0, 0, 0, 0, 0", "fixed pose of the scan's frame in the odometry's "
                                   "child frame: 'x, y, z, roll, pitch, yaw' [m, rad] (identity when the "
                                   "odometry is the sensor's own)")

    fuse_at_rest: bool = param(True, "without odometry, fuse at identity the recent scans (up to accumulate_scans, "
                                "within accumulate_max_age) that the scans themselves show were taken at rest: a "
                                "resting non-repeating LiDAR fills in its field of view; a scan that moved is "
                                "registered alone")
    rest_wait: float = param(1.0, "without odometry and with fuse_at_rest, the first registration after activation "
                              "waits at most this for accumulate_scans scans, so a robot switched on at rest starts "
                              "from a fused scan [s]; 0 = no wait", 0.0, 60.0)

    base_frame: str = param("", "the robot's base frame: pose and pose_with_covariance give its pose (Nav2's "
                             "/initialpose wants it) instead of the source frame's; '' = the source frame's")
    base_to_sensor: str = param("0, 0, 0, 0, 0, 0", "fixed pose of the source cloud's frame in base_frame: "
                                 "'x, y, z, roll, pitch, yaw' [m, rad] (the sensor's mounting; this node does "
                                 "not look up tf)")

    verify_rate: float = param(0.0, "map mode, the watchdog: checks per second of the localization stack's pose "
                                "on tracked_pose against the newest scan (fused as relocalization fuses it); the "
                                "verdict goes out on status and /diagnostics; 0 = off (read only)", 0.0, 100.0)
    tracked_pose_type: str = param("pose_with_covariance", "the message type on tracked_pose: pose_with_covariance "
                                    "(geometry_msgs/PoseWithCovarianceStamped, AMCL's amcl_pose) or odometry "
                                    "(nav_msgs/Odometry in the map frame) (read only)")
    lost_after: int = param(3, "the watchdog's failed checks in a row after which the robot is lost: the node "
                             "relocalizes globally and publishes the pose it finds on pose_with_covariance", 1, 1000)
    max_pose_age: float = param(0.5, "the watchdog checks the tracked pose nearest the scan's stamp only when it is "
                                 "at most this far from it [s]", 0.0, 3600.0)

    imu_topic: str = param("", "sensor_msgs/Imu topic giving the source sensor's up direction for the gravity "
                            "prior (gravity.source_up follows it; gravity.target_up must be set): the reported "
                            "orientation, or the mean acceleration over imu_window when there is none; '' = "
                            "gravity.source_up as set (read only)")
    imu_window: float = param(1.0, "seconds of IMU accelerations before a scan averaged into its up "
                                   "direction", 0.01, 60.0)
    sensor_to_imu: str = param("0, 0, 0, 0, 0, 0", "fixed pose of the IMU in the source cloud's frame: 'x, y, z, "
                                "roll, pitch, yaw' [m, rad]; only its rotation is used")

    def accumulation(self) -> AccumulationLimits:
        """How many scans to fuse and how far back, with the auto default resolved."""
        scans = self.accumulate_scans or (5 if self.mode == "map" else 1)
        return AccumulationLimits(scans, self.accumulate_max_distance, self.accumulate_max_age,
                                  self.odometry_tolerance)

    def odometry_extrinsic(self) -> np.ndarray:
        """T_child_scan from odometry_to_scan; ConfigError when malformed."""
        return parse_pose(self.odometry_to_scan, "odometry_to_scan")

    def base_extrinsic(self) -> np.ndarray:
        """T_base_sensor from base_to_sensor; ConfigError when malformed."""
        return parse_pose(self.base_to_sensor, "base_to_sensor")

    def imu_extrinsic(self) -> np.ndarray:
        """T_sensor_imu from sensor_to_imu; ConfigError when malformed."""
        return parse_pose(self.sensor_to_imu, "sensor_to_imu")

    def viewpoints(self):
        """(source, target) sensor positions for the core: (3,) tuples or None when unknown."""
        return (parse_viewpoint(self.source_viewpoint, "source_viewpoint", ORIGIN),
                parse_viewpoint(self.target_viewpoint, "target_viewpoint",
                                None if self.mode == "map" else ORIGIN))


def parse_pose(text: str, name: str) -> np.ndarray:
    """4x4 transform of 'x, y, z, roll, pitch, yaw' (metres, radians, fixed-axis roll-pitch-yaw as
    tf2 and URDF use it); ConfigError when malformed."""
    values = parse_numbers(text, 6, name, "'x, y, z, roll, pitch, yaw' in metres and radians")
    return to_matrix(Rotation.from_euler("xyz", values[3:]).as_matrix(), np.array(values[:3]))


CHOICES = {"mode": MODE_CHOICES, "registration": REGISTRATION_CHOICES, "source_qos": QOS_KINDS, "target_qos": QOS_KINDS,
           "tracked_pose_type": TRACKED_POSE_TYPES, "preset": PRESETS, **CORE_CHOICES}
READ_ONLY = {"autostart", "preset", "source_qos", "target_qos", "diagnostics_period", "map_file", "map_frame",
             "map_trajectory_file", "map_cache", "map_cache_dir", "imu_topic", "verify_rate", "tracked_pose_type"}


def _descriptor(name: str, field: dataclasses.Field, value) -> ParameterDescriptor:
    desc = ParameterDescriptor(description=field.metadata["description"],
                               read_only=name in READ_ONLY)
    if name in CHOICES:
        desc.additional_constraints = "one of: " + ", ".join(CHOICES[name])
    low, high = field.metadata["range"]
    if low is not None and not isinstance(value, (bool, list)):
        if isinstance(value, int):
            desc.integer_range = [IntegerRange(from_value=int(low), to_value=int(high), step=1)]
        else:
            desc.floating_point_range = [FloatingPointRange(from_value=float(low),
                                                            to_value=float(high), step=0.0)]
    return desc


PRESET_FIELD = param("indoor", "preset the core parameters start from: indoor, outdoor or object "
                      "(read only; set at start, e.g. in the parameter file)")


def declare_parameters(node) -> tuple[RegorConfig, NodeSettings]:
    """Declare every parameter and return the configuration they hold (overrides applied)."""
    preset = node.declare_parameter("preset", "indoor", _descriptor("preset", PRESET_FIELD, "")).value
    if preset not in PRESETS:
        raise ConfigError(f"preset={preset!r}: choose one of {', '.join(PRESETS)}")
    values = {}
    for f in dataclasses.fields(NodeSettings):
        default = f.default
        values[f.name] = node.declare_parameter(f.name, default, _descriptor(f.name, f, default)).value
    settings = make_settings(values)
    core = {}
    for name, default, f in RegorConfig.preset(preset).parameters():
        core[name] = node.declare_parameter(name, default, _descriptor(name, f, default)).value
    config = RegorConfig.preset(preset).replace(core)
    return config, settings


def unknown_overrides(node) -> list[str]:
    """A warning for each parameter given at start (-p, --params-file) that the node does not
    declare: rclpy ignores it silently, so a misspelt name would leave its default in force."""
    given = getattr(node, "_parameter_overrides", {})   # rclpy keeps them here (Humble to Kilted)
    names = [n for n in given if not node.has_parameter(n) and not n.startswith("qos_overrides.")]
    declared = list(node.get_parameters_by_prefix("")) if names else []
    leaves = {name.rsplit(".", 1)[-1]: name for name in declared}
    warnings = []
    in_metres = RegorConfig().lengths()
    for name in sorted(names):
        if name in in_metres:   # set in voxels since 2026-12: say the value to give
            warnings.append(_in_voxels(name, given[name].value, node.get_parameter("features.voxel_size").value))
            continue
        close = difflib.get_close_matches(name, declared, n=1) or \
            [leaves[m] for m in difflib.get_close_matches(name.rsplit(".", 1)[-1], list(leaves), n=1)]
        hint = f"; did you mean '{close[0]}'?" if close else ""
        warnings.append(f"parameter '{name}' is not one of register_node's: ignored{hint}")
    return warnings


def unused_settings(config: RegorConfig, settings: NodeSettings) -> list[str]:
    """A warning for each setting given that the others leave without effect, so the user is not
    left believing it works."""
    warnings = []
    if settings.imu_topic and config.gravity.target_up.strip().lower() == "unknown":
        warnings.append(f"imu_topic '{settings.imu_topic}' gives the scan's up, but gravity.target_up is unknown: "
                        "the gravity prior needs both and stays off; give the map's up in its frame (a "
                        "gravity-aligned map, as LIO-SAM builds: '0 0 1'; FAST-LIO's map is its IMU's first "
                        "frame, level only if it started level)")
    return warnings


def _in_voxels(name: str, metres, voxel: float) -> str:
    """The warning for a length given in metres by the name the code reads it under."""
    if not isinstance(metres, (int, float)) or isinstance(metres, bool):
        return f"parameter '{name}' is set in voxels now, as '{name}_voxels': ignored"
    return (f"parameter '{name}' is set in voxels now: ignored; give '{name}_voxels:={metres / voxel:g}' "
            f"({metres:g} m at features.voxel_size {voxel:g} m)")


def make_settings(values: dict) -> NodeSettings:
    """NodeSettings from a dict of values, checking choices and ranges."""
    for name, choices in CHOICES.items():
        if name in values and values[name] not in choices:
            raise ConfigError(f"{name}={values[name]!r}: choose one of {', '.join(choices)}")
    settings = NodeSettings(**values)
    for f in dataclasses.fields(NodeSettings):
        low, high = f.metadata["range"]
        value = getattr(settings, f.name)
        if low is not None and not low <= value <= high:
            raise ConfigError(f"{f.name}={value!r} is outside its valid range [{low}, {high}]")
    settings.viewpoints()  # raises on a malformed viewpoint
    settings.odometry_extrinsic()  # and on a malformed extrinsic
    settings.base_extrinsic()
    settings.imu_extrinsic()
    if settings.map_file and settings.mode != "map":
        raise ConfigError(f"map_file={settings.map_file!r} is for mode=map (a pair's target comes on target_cloud)")
    if settings.verify_rate and settings.mode != "map":
        raise ConfigError("verify_rate: the watchdog checks a pose in a map (mode=map)")
    if settings.initial_guess_min_radius > settings.initial_guess_max_radius:
        raise ConfigError("initial_guess_min_radius is larger than initial_guess_max_radius")
    return settings


def typed_settings(changes: dict) -> dict:
    """Node settings written as text (a command line's NAME=VALUE) as their fields' types; core
    settings pass through (RegorConfig.replace types them). ConfigError names a value that is not."""
    defaults = {f.name: f.default for f in dataclasses.fields(NodeSettings)}
    return {name: coerce(name, value, defaults[name]) if name in defaults else value
            for name, value in changes.items()}


def apply_changes(config: RegorConfig, settings: NodeSettings,
                  changes: dict) -> tuple[RegorConfig, NodeSettings]:
    """The configuration after a batch of parameter changes; raises ConfigError with the reason."""
    node_names = {f.name for f in dataclasses.fields(NodeSettings)}
    node_changes = {k: v for k, v in changes.items() if k in node_names}
    core_changes = {k: v for k, v in changes.items() if k not in node_names}
    unknown = [k for k in core_changes if k not in config.to_flat()]
    if unknown:
        raise ConfigError(f"unknown parameter {unknown[0]!r}")
    new_settings = make_settings({**dataclasses.asdict(settings), **node_changes})
    return config.replace(core_changes), new_settings
