"""The node's work without ROS: the inputs, the map in use, the scans and odometry to fuse, and the
worker thread that prepares maps, registers and checks the stack's pose (ros/watchdog.py).

register_node converts messages and hands them here, and publishes what this reports (each
registration's Outcome, the map as prepared). One lock guards the state: callbacks (the
executor's threads), the worker and the services all go through it. A map is loaded one way,
whoever asks (configure, the load_map service, the worker after a feature setting changed), and
the map in use changes only when the new one is ready.
"""
from __future__ import annotations

import dataclasses
import re
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING
from urllib.parse import parse_qs, urlparse

import numpy as np

from ..core import (
    PreparedCloud,
    RegistrationError,
    ScanHistory,
    SearchRegion,
    attached_pose,
    prepare_cloud,
    register,
    verify,
    warm_up,
)
from ..io.map_file import load_map_file
from .diagnostics import Health
from .imu_up import ImuUp
from .inputs import CheckPose, Cloud, InputBuffer, Job, MapKey, PrepareMap, Register
from .watchdog import LOST, Check, TrackedPose, Watchdog

if TYPE_CHECKING:
    from ..core import RegistrationResult

WARN_THROTTLE_S = 5.0


@dataclass(frozen=True)
class Hint:
    """Where the source is thought to be (an initial guess), in the frame it was given in."""

    frame_id: str
    region: SearchRegion


@dataclass(frozen=True)
class PublishedPose:
    """The pose that goes out: the sensor's in the target frame, or its base's with a base_frame."""

    transform: np.ndarray   # 4x4
    covariance: np.ndarray  # 6x6 over (x, y, z, roll, pitch, yaw)


@dataclass(frozen=True)
class Answer:
    """What one registration came to, for a relocalize call waiting for it."""

    serial: int        # the source cloud's (InputBuffer's count), 0 before any
    accepted: bool     # the pose was published as accepted
    text: str          # what happened, in a line


@dataclass(frozen=True)
class Outcome:
    """One registration, for the node to publish."""

    source: Cloud
    result: RegistrationResult
    target_frame: str
    status: dict       # the status message's fields beside the result's own
    pose: PublishedPose | None  # None when withheld
    sensor_to_base: np.ndarray | None  # T_base_sensor inverted, with a base_frame (the candidates')
    answer: str        # what happened, in a line (a relocalize call's reply)


class Localizer:
    """The state of one node and its worker; ``logger`` has info / warning / error (rclpy's or
    logging's), ``on_outcome`` and ``on_map`` publish (they run on the worker or a service thread)."""

    def __init__(self, config, settings, logger, on_outcome: Callable[[Outcome], None],
                 on_map: Callable[[PreparedCloud, str], None], on_check: Callable[[Check], None]):
        self.lock = threading.Condition()
        self.config, self.settings = config, settings
        self.logger, self._on_outcome, self._on_map, self._on_check = logger, on_outcome, on_map, on_check
        self.stats = {"source_clouds": 0, "target_clouds": 0, "odometry_messages": 0, "registrations": 0,
                      "accepted_poses": 0, "dropped_stale": 0, "bad_inputs": 0, "map_preparations": 0}
        self.health = Health(counters=self.stats, map_from_file=bool(settings.map_file))
        self.active = False
        self._stopping = False
        self._worker: threading.Thread | None = None
        self.reset()

    def reset(self) -> None:
        """The inputs, the map and the answers of one configured lifetime (the caller holds the lock)."""
        self._inputs = InputBuffer()
        self.map: PreparedCloud | None = None
        self.map_frame = ""
        self._map_key: MapKey | None = None
        self._hint: Hint | None = None                 # in force until a pose is accepted
        self._answer = Answer(0, False, "")            # the latest registration's
        self._history = ScanHistory(self._history_capacity())   # scans and odometry, for accumulation
        self._imu = ImuUp() if self.settings.imu_topic else None  # the source's up, for the gravity prior
        self._warned: dict[str, float] = {}            # kind of bad input -> when it was last logged
        self.watchdog = Watchdog()                     # the stack's poses and the checks' run of failures
        self._check_due = False                        # verify_rate's timer asked for a check
        self._checked = 0                              # the serial of the last source checked: each once
        self._relocalizing = False                     # the watchdog asked for the next registration
        self.health.watchdog = None

    # --- lifecycle ---

    def configure(self) -> float:
        """Compile the registration kernels (or load them from numba's disk cache), so that the
        first relocalization does not pay it, and load the map file (RegistrationError with the
        reason when it cannot be used); the kernels' seconds."""
        start = time.perf_counter()
        warm_up()
        kernels_s = time.perf_counter() - start
        self.logger.info(f"registration kernels ready in {kernels_s:.2f} s")
        self.release()
        with self.lock:
            self._stopping = False
            settings = self.settings
        if settings.map_file:
            self.use_map_file(settings.map_file, settings.map_trajectory_file)
        return kernels_s

    def start(self) -> None:
        self._worker = threading.Thread(target=self._work, name="regor_worker", daemon=True)
        self._worker.start()

    def set_active(self, active: bool) -> None:
        """Start or stop taking inputs; activated with a map file, the map goes out (for RViz)."""
        with self.lock:
            self.active = active
            self.lock.notify_all()
            prepared, frame, from_file = self.map, self.map_frame, bool(self.settings.map_file)
        if active and from_file and prepared is not None:
            self._on_map(prepared, frame)

    def release(self) -> None:
        """Drop the map and the inputs (the node's cleanup, and a fresh start's configure)."""
        with self.lock:
            self.reset()
            self.health.map_info = {}

    def stop(self, timeout: float) -> None:
        """Stop the worker: wait up to timeout for it to finish (a registration or map preparation
        under way is abandoned; it reports nothing once stopping) and wake a waiting relocalize call."""
        with self.lock:
            self._stopping = True
            self.active = False
            self.lock.notify_all()
        if self._worker is not None:
            self._worker.join(timeout)
            self._worker = None

    # --- inputs ---

    def store(self, which: str, header, stamp: float, points: np.ndarray) -> None:
        """The newest cloud on source_cloud or target_cloud (a source also joins the scan history)."""
        with self.lock:
            self.stats[f"{which}_clouds"] += 1
            self.stats["dropped_stale"] += self._inputs.store(which, header, stamp, points, self.settings.mode)
            if which == "source":
                self._history.add_scan(stamp, points, self._history_capacity())
            self.lock.notify_all()

    def replay(self, header, stamp: float, points: np.ndarray, register_it: bool,
               check_it: bool = False) -> Answer | None:
        """Offline (regor-replay; no worker runs): a scan stored as a source message is; with
        ``check_it`` the watchdog checks the stack's pose on it (on_check), and with
        ``register_it``, or when the check finds the robot lost, it is registered here and now as
        the worker would (fused along odometry, judged, reported through on_outcome): a recording
        replayed as fast as the CPU allows."""
        self.store("source", header, stamp, points)
        if check_it:
            with self.lock:
                config, settings, source = self.config, self.settings, self._inputs.source
            self._check(source, config, settings)
            with self.lock:
                register_it |= self._relocalizing
        if not register_it:
            return None
        with self.lock:
            relocalizing, self._relocalizing, self._inputs.relocalize_after = self._relocalizing, False, None
            job = Register(self._inputs.source, None)
            self._inputs.taken(job)
            config, settings, hint = self.config, self.settings, self._hint
        answer = self._register(job, config, settings, hint)
        if relocalizing and answer.accepted:
            with self.lock:
                self.watchdog.found()
        return answer

    def add_odometry(self, stamp: float, T_odom_scan: np.ndarray) -> None:
        with self.lock:
            self.stats["odometry_messages"] += 1
            self._history.add_odometry(stamp, T_odom_scan)

    def add_imu(self, stamp: float, orientation_xyzw: np.ndarray | None, acceleration: np.ndarray) -> None:
        with self.lock:
            if self._imu is not None:
                self._imu.add(stamp, orientation_xyzw, acceleration)

    def track_pose(self, pose: TrackedPose) -> None:
        """The localization stack's pose (tracked_pose), for the watchdog."""
        with self.lock:
            self.watchdog.track(pose)

    def request_check(self) -> None:
        """verify_rate's tick: check the stack's pose on the newest source (map mode, a map ready)."""
        with self.lock:
            self._check_due = True
            self.lock.notify_all()

    def set_hint(self, hint: Hint) -> None:
        with self.lock:
            self._hint = hint
            self.lock.notify_all()

    def bad_input(self, text: str) -> None:
        """Count and warn, at most once per WARN_THROTTLE_S for each kind of problem (the text
        with its numbers blanked), so a flood of one bad kind cannot hide another."""
        kind = re.sub(r"[-+.\de]*\d[-+.\de]*", "#", text)
        now = time.monotonic()
        with self.lock:
            self.stats["bad_inputs"] += 1
            self.health.last_bad_input = text
            if now - self._warned.get(kind, -WARN_THROTTLE_S) < WARN_THROTTLE_S:
                return
            self._warned[kind] = now
        self.logger.warning(text)

    def _history_capacity(self) -> int:
        """Scans kept for accumulation: twice the scans fused, so ones without odometry can be skipped."""
        return 2 * self.settings.accumulation().scans + 2

    # --- requests ---

    def relocalize(self) -> Answer:
        """The registration of the next source, waiting for it up to relocalize_timeout."""
        timeout = self.settings.relocalize_timeout
        if not self.active:
            return Answer(0, False, f"not registering: the node is {self.health.lifecycle} (activate it)")
        with self.lock:
            after = self._inputs.serials["source"]
            self._inputs.relocalize_after = after
            self.lock.notify_all()
            answered = self.lock.wait_for(lambda: self._answer.serial > after or self._stopping, timeout)
            self._inputs.relocalize_after = None
            answer = self._answer
            no_map = self.settings.mode == "map" and self.map is None
        if answered:
            return answer
        waiting = "no map yet" if no_map else "no source cloud arrived"
        return Answer(answer.serial, False, f"{waiting} within relocalize_timeout={timeout:g} s")

    def change(self, changed) -> None:
        """Apply ``changed(config, settings) -> (config, settings)`` (a parameter change; it raises
        ConfigError to refuse); registrations under way keep the settings they started with."""
        with self.lock:
            self.config, self.settings = changed(self.config, self.settings)

    def use_map_url(self, map_url: str) -> None:
        """Load the map a nav_msgs/LoadMap request names: its path or file:// URL, with
        ``?trajectory=PATH`` for its TUM trajectory. FileNotFoundError (and the map in use stays)
        when a file is not there, RegistrationError when it is not usable."""
        url = urlparse(map_url)
        path = url.path if url.scheme in ("", "file") else ""
        trajectory = parse_qs(url.query).get("trajectory", [""])[0]
        missing = [p for p in (path, trajectory) if p and not Path(p).expanduser().is_file()]
        if not path or missing:
            raise FileNotFoundError(missing[0] if missing else repr(map_url))
        self.use_map_file(path, trajectory)

    def use_map_file(self, path: str, trajectory: str) -> None:
        """Load (or prepare and cache) a map file and register against it from now on; the map in
        use stays until then, and stays when this raises RegistrationError (with the reason)."""
        with self.lock:
            config, settings = self.config, self.settings
        key = MapKey.of_file(path, trajectory, config.features)

        def load():
            loaded = load_map_file(path, config, trajectory or None, settings.map_cache,
                                   settings.map_cache_dir, warn=self.logger.warning)
            return loaded.prepared, loaded.info

        prepared = self._use_map(load, key, settings.map_frame, (path, trajectory))
        with self.lock:  # for RViz: the map as the node uses it (not while its publishers go away)
            if prepared is not None and self.active and not self._stopping:
                self._on_map(prepared, settings.map_frame)

    def _use_map(self, prepare, key: MapKey, frame: str, file: tuple[str, str] | None = None) -> PreparedCloud | None:
        """Run ``prepare`` (-> prepared map, info) and make its map the one registered against; a
        map ``file`` (path, trajectory) becomes the settings' map file in the same step (other
        settings changed meanwhile are kept). None when the node stopped meanwhile."""
        self.health.preparing_map = True
        start = time.perf_counter()
        try:
            prepared, info = prepare()
        finally:
            self.health.preparing_map = False
        seconds = time.perf_counter() - start
        with self.lock:
            if self._stopping:  # the node's publishers are going away
                return None
            self.map, self._map_key, self.map_frame = prepared, key, frame
            if file is not None:
                self.settings = dataclasses.replace(self.settings, map_file=file[0], map_trajectory_file=file[1])
                self.health.map_from_file = True
            self.stats["map_preparations"] += 1
            self.health.last_error = ""
            self.health.map_info = {
                "map_points": prepared.input_size, "map_keypoints": len(prepared),
                "map_exact_search": prepared.index.exact, **info,
                "map_preparation_seconds": round(seconds, 3)}
            self.lock.notify_all()
        cache = f", cache {info['map_cache']}" if info.get("map_cache") else ""
        self.logger.info(f"map prepared: {prepared.input_size} points, {len(prepared)} keypoints "
                         f"in {seconds:.1f} s{cache}")
        return prepared

    # --- the worker ---

    def _next_job(self) -> Job | None:
        if not self.active:
            return None
        job = self._inputs.next_job(self.settings, self.config.features, self._map_key, self.map is not None)
        source = self._inputs.source
        if (self._check_due and self.map is not None and source is not None and source.serial > self._checked
                and not isinstance(job, PrepareMap)):
            return CheckPose(source)
        return job

    def _work(self) -> None:
        while True:
            with self.lock:
                job = self._next_job()
                while job is None and not self._stopping:
                    self.lock.wait(0.5)
                    job = self._next_job()
                if self._stopping:
                    return
                config, settings, hint = self.config, self.settings, self._hint
                if isinstance(job, Register):
                    self._inputs.taken(job)
                if isinstance(job, CheckPose):
                    self._check_due, self._checked = False, job.source.serial
            if isinstance(job, PrepareMap):
                self._prepare_map(job, config, settings)
            elif isinstance(job, CheckPose):
                self._check(job.source, config, settings)
            else:
                answer = self._register(job, config, settings, hint)
                with self.lock:
                    self._answer = answer
                    if self._relocalizing:  # the watchdog's relocalization: the robot found, or not yet
                        self._relocalizing, self._inputs.relocalize_after = False, None
                        if answer.accepted:
                            self.watchdog.found()
                    self.lock.notify_all()

    def _prepare_map(self, job: PrepareMap, config, settings) -> None:
        """Prepare the map once per message or file (and feature settings); queries wait meanwhile."""
        key = job.key
        try:
            if key.file:
                self.use_map_file(key.file, key.trajectory)
            else:
                self._use_map(lambda: (prepare_cloud(job.target.points, config, "target",
                                                     viewpoint=key.viewpoint), {}),
                              key, job.target.header.frame_id)
        except RegistrationError as exc:
            with self.lock:  # no map, and not prepared again until its source or the feature settings change
                if not self._stopping:
                    self.map, self._map_key, self.map_frame = None, key, ""
            self.health.last_error = f"map not usable: {exc}"
            self.bad_input(f"map skipped: {exc}")

    def _check(self, src: Cloud, config, settings) -> None:
        """The watchdog's check of the stack's pose at the source's stamp, on the source fused as a
        relocalization fuses it; lost, the next source is registered (Watchdog)."""
        with self.lock:
            pose, why = self.watchdog.pose_for(src.stamp, self.map_frame, settings.max_pose_age)
            target = self.map
        result = None
        if pose is not None:
            T_map_sensor = pose.transform @ settings.base_extrinsic() if settings.base_frame else pose.transform
            source, viewpoints, _ = self._source_input(src, settings)
            try:
                result = verify(source, target, T_map_sensor, config, **viewpoints)
            except RegistrationError as exc:
                why = f"not checked: {exc}"
        with self.lock:
            if self._stopping:
                return
            check = (self.watchdog.unchecked(why, src.stamp) if result is None else
                     self.watchdog.judged(result, src.stamp, pose.stamp, settings.lost_after))
            if check.state == LOST and self._inputs.relocalize_after is None:
                self._relocalizing, self._inputs.relocalize_after = True, src.serial - 1
            self.health.watchdog = check
            self._on_check(check)
        if check.state == LOST:
            self.logger.error(f"lost: {check.failures} failed checks in a row ({check.reason}); relocalizing")
        elif result is not None and not result.accepted:
            self.logger.warning(f"tracked pose suspect: {check.reason}")

    def _gravity(self, config, settings, src: Cloud):
        """The configuration with the source's up direction from the IMU at the scan's stamp (or
        unknown when the IMU gave none: no prior rather than a stale one), and what it was."""
        if self._imu is None:
            return config, {"direction": config.gravity.source_up, "from": "gravity.source_up"}
        with self.lock:
            up, where = self._imu.up_at(src.stamp, settings.imu_window, settings.imu_extrinsic()[:3, :3])
        text = "unknown" if up is None else " ".join(f"{v:.6f}" for v in up)
        return config.replace({"gravity.source_up": text}), {"direction": text, "from": where}

    def _region(self, hint: Hint | None, target_frame: str) -> SearchRegion | None:
        """The hint's search region, or None; a hint in another frame is dropped with a warning."""
        if hint is None:
            return None
        if hint.frame_id and hint.frame_id != target_frame:
            with self.lock:
                if self._hint is hint:
                    self._hint = None
            self.bad_input(f"initial_guess dropped: it is in '{hint.frame_id}', the target "
                           f"cloud in '{target_frame}' (this node does not look up tf)")
            return None
        return hint.region

    def _source_input(self, src: Cloud, settings):
        """(the scan alone, or fused with the scans before it along odometry (accumulate_scans);
        the viewpoints to give register() and verify() with it; what was fused, for status). The
        fused scans carry their own viewpoints (the scan frame's origin)."""
        source_viewpoint, target_viewpoint = settings.viewpoints()
        limits = settings.accumulation()
        sequence, info = None, None
        if limits.scans >= 2:
            with self.lock:
                sequence, info = self._history.sequence(src.stamp, limits, source_viewpoint)
        if sequence is None:
            return src.points, {"source_viewpoint": source_viewpoint, "target_viewpoint": target_viewpoint}, info
        return sequence, {"target_viewpoint": target_viewpoint}, info

    def _register(self, job: Register, config, settings, hint: Hint | None) -> Answer:
        """Register the source against the pair's target or (map mode) the prepared map, and
        report it."""
        src = job.source
        if settings.mode == "map":
            with self.lock:
                target, target_frame = self.map, self.map_frame
        else:
            target, target_frame = job.target.points, job.target.header.frame_id
        try:
            config, source_up = self._gravity(config, settings, src)
            region = self._region(hint, target_frame)
            source, viewpoints, accumulation = self._source_input(src, settings)
            result = register(source, target, config, search_region=region, **viewpoints)
        except RegistrationError as exc:
            self.health.last_error = str(exc)
            self.bad_input(f"registration skipped: {exc}")
            return Answer(src.serial, False, f"registration skipped: {exc}")
        except Exception as exc:  # keep the node alive whatever the input did
            self.health.last_error = f"{type(exc).__name__}: {exc}"
            self.logger.error(f"registration failed: {type(exc).__name__}: {exc}")
            return Answer(src.serial, False, f"registration failed: {type(exc).__name__}: {exc}")
        with self.lock:
            if self._stopping:  # the node's publishers are going away
                return Answer(src.serial, False, "node stopping")
            self.stats["registrations"] += 1
            self.stats["accepted_poses"] += int(result.accepted)
            self.health.last_error = self.health.last_bad_input = ""
            self.health.last_summary = result.summary()
            if result.accepted and region is not None and self._hint is hint:
                self._hint = None  # the robot is found: the hint has done its job
            status = {"source_stamp": src.stamp, "source_frame": src.header.frame_id,
                      "target_stamp": None if job.target is None else job.target.stamp,
                      "target_frame": target_frame, "pose_of": settings.base_frame or src.header.frame_id,
                      "mode": settings.mode, **self.stats, **self.health.inputs, "accumulation": accumulation,
                      "source_up": source_up, "target_up": config.gravity.target_up,
                      **(self.health.map_info if settings.mode == "map" else {}),
                      "search_region": None if region is None else {
                          "centre": [float(v) for v in region.centre], "radius": region.radius}}
        figures = (f"{result.num_inliers} inliers, fitness {result.fitness:.2f}, "
                   f"{result.timings['total']:.2f} s")
        if result.accepted:
            alone = ", which single it out among the other answers" if result.verdict.singled_out else ""
            figures = f"carried by its {result.verdict.carried_by}{alone}, {figures}"
            self.logger.info(f"pose accepted: {figures}")
            answer = f"pose published ({figures})"
        else:
            if accumulation and accumulation.get("more_to_fuse"):
                figures += (f"; {accumulation['scans_fused']} of {settings.accumulation().scans} scans fused: up to "
                            f"{accumulation['more_to_fuse']} more are fused as they arrive with odometry")
            self.logger.warning(f"pose rejected: {result.reason} ({figures})")
            answer = (f"pose published although rejected: {result.reason}" if settings.publish_rejected
                      else f"pose withheld: {result.reason} ({figures})")
        base = np.linalg.inv(settings.base_extrinsic()) if settings.base_frame else None
        pose = None
        if result.accepted or settings.publish_rejected:
            # the robot's pose, for Nav2: the sensor's composed with its mounting
            pose = (PublishedPose(result.transform, result.covariance) if base is None
                    else PublishedPose(*attached_pose(result.transform, result.covariance, base)))
        with self.lock:  # stop() takes the lock before the node's publishers go away
            if self._stopping:
                return Answer(src.serial, False, "node stopping")
            self._on_outcome(Outcome(src, result, target_frame, status, pose, base, answer))
        return Answer(src.serial, result.accepted, answer)
