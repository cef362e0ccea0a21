"""The node's work without ROS: the inputs, and the worker thread that prepares maps, registers and
checks the stack's pose (ros/watchdog.py).

register_node converts messages and hands them here, and publishes what this reports (each
registration's Outcome, the map as prepared, each check). Its parts each do one job: the map in use
(map_slot.py), what a registration is given beside the scan (source_context.py) and what the node
reports (report.py); one lock guards them all (shared.py).
"""
from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..core import PreparedCloud, RegistrationError, register, verify, warm_up
from .inputs import CheckPose, Cloud, InputBuffer, Job, PrepareMap, Register
from .map_slot import MapSlot
from .report import Outcome, Report
from .shared import Shared
from .source_context import Hint, SourceContext
from .watchdog import LOST, Check, TrackedPose, Watchdog


@dataclass(frozen=True)
class Answer:
    """What one registration came to, for a relocalize call waiting for it."""

    serial: int        # the source cloud's (InputBuffer's count), 0 before any
    accepted: bool     # the pose was published as accepted
    text: str          # what happened, in a line


class Localizer:
    """One node's inputs and worker; ``logger`` has info / warning / error (rclpy's or logging's),
    ``on_outcome``, ``on_map`` and ``on_check`` publish (they run on the worker or a service thread)."""

    def __init__(self, config, settings, logger, on_outcome: Callable[[Outcome], None],
                 on_map: Callable[[PreparedCloud, str], None], on_check: Callable[[Check], None]):
        self.shared = Shared(config, settings)
        self.lock = self.shared.lock
        self.report = Report(self.lock, logger, map_from_file=bool(settings.map_file))
        self.maps = MapSlot(self.shared, self.report, on_map)
        self._on_outcome, self._on_check = on_outcome, on_check
        self._worker: threading.Thread | None = None
        self.release()

    def release(self) -> None:
        """Drop the map and the inputs: what one configured lifetime gathered (the node's cleanup,
        and a fresh start's configure)."""
        with self.lock:
            self._inputs = InputBuffer()
            self.maps.clear()
            self.context = SourceContext(self.shared, self.report)
            self._answer = Answer(0, False, "")            # the latest registration's
            self.watchdog = Watchdog()                     # the stack's poses and the checks' run of failures
            self._check_due = False                        # verify_rate's timer asked for a check
            self._checked = 0                              # the serial of the last source checked: each once
            self._relocalizing = False                     # the watchdog asked for the next registration
            self.report.health.watchdog = None
            self.report.health.map_info = {}

    # --- lifecycle ---

    def configure(self) -> float:
        """Compile the registration kernels (or load them from numba's disk cache), so that the
        first relocalization does not pay it, and load the map file (RegistrationError with the
        reason when it cannot be used); the kernels' seconds."""
        start = time.perf_counter()
        warm_up()
        kernels_s = time.perf_counter() - start
        self.report.logger.info(f"registration kernels ready in {kernels_s:.2f} s")
        self.release()
        with self.lock:
            self.shared.stopping = False
            settings = self.shared.settings
        if settings.map_file:
            self.maps.use_file(settings.map_file, settings.map_trajectory_file)
        return kernels_s

    def set_active(self, active: bool) -> None:
        """Start or stop taking inputs (the worker starts with the first activation); activated with
        a map file, the map goes out (for RViz)."""
        if active and self._worker is None:
            self._worker = threading.Thread(target=self._work, name="regor_worker", daemon=True)
            self._worker.start()
        with self.lock:
            self.shared.active = active
            self.lock.notify_all()
            prepared, frame, from_file = self.maps.prepared, self.maps.frame, bool(self.shared.settings.map_file)
        if active and from_file and prepared is not None:
            self.maps.publish(prepared, frame)

    def stop(self, timeout: float) -> None:
        """Stop the worker: wait up to timeout for it to finish (a registration or map preparation
        under way is abandoned; it reports nothing once stopping) and wake a waiting relocalize call."""
        with self.lock:
            self.shared.stopping = True
            self.shared.active = False
            self.lock.notify_all()
        if self._worker is not None:
            self._worker.join(timeout)
            self._worker = None

    # --- inputs and requests ---

    def store(self, which: str, frame_id: str, stamp_ns: int, points: np.ndarray) -> None:
        """The newest cloud on source_cloud or target_cloud (a source also joins the scan history)."""
        with self.lock:
            stats = self.report.stats
            stats[f"{which}_clouds"] += 1
            stats["dropped_stale"] += self._inputs.store(which, frame_id, stamp_ns, points, self.shared.settings.mode)
            source = self._inputs.source
            if which == "source" and source is not None:   # (just stored)
                self.context.add_scan(source.stamp, points)
            self.lock.notify_all()

    def replay(self, frame_id: str, stamp_ns: int, points: np.ndarray, register_it: bool,
               check_it: bool = False) -> Answer | None:
        """Offline (regor-replay; no worker runs): a scan stored as a source message is; with
        ``check_it`` the watchdog checks the stack's pose on it (on_check), and with
        ``register_it``, or when the check finds the robot lost, it is registered here and now as
        the worker would (fused along odometry, judged, reported through on_outcome): a recording
        replayed as fast as the CPU allows."""
        self.store("source", frame_id, stamp_ns, points)
        source = self._inputs.source
        assert source is not None, "just stored"
        if check_it:
            with self.lock:
                config, settings = self.shared.config, self.shared.settings
            self._check(source, config, settings)
            with self.lock:
                register_it |= self._relocalizing
        if not register_it:
            return None
        with self.lock:
            relocalizing, self._relocalizing, self._inputs.relocalize_after = self._relocalizing, False, None
            job = Register(source, None)
            self._inputs.taken(job)
            config, settings, hint = self.shared.config, self.shared.settings, self.context.hint
        answer = self._register(job, config, settings, hint)
        if relocalizing and answer.accepted:
            with self.lock:
                self.watchdog.found()
        return answer

    def track_pose(self, pose: TrackedPose) -> None:
        """The localization stack's pose (tracked_pose), for the watchdog."""
        with self.lock:
            self.watchdog.track(pose)

    def request_check(self) -> None:
        """verify_rate's tick: check the stack's pose on the newest source (map mode, a map ready)."""
        with self.lock:
            self._check_due = True
            self.lock.notify_all()

    def relocalize(self) -> Answer:
        """The registration of the next source, waiting for it up to relocalize_timeout."""
        settings = self.shared.settings
        if not self.shared.active:
            return Answer(0, False, f"not registering: the node is {self.report.health.lifecycle} (activate it)")
        with self.lock:
            after = self._inputs.serials["source"]
            self._inputs.relocalize_after = after
            self.lock.notify_all()
            answered = self.lock.wait_for(lambda: self._answer.serial > after or self.shared.stopping,
                                          settings.relocalize_timeout)
            self._inputs.relocalize_after = None
            answer = self._answer
            no_map = self.shared.settings.mode == "map" and self.maps.prepared is None
        if answered:
            return answer
        waiting = "no map yet" if no_map else "no source cloud arrived"
        return Answer(answer.serial, False, f"{waiting} within relocalize_timeout={settings.relocalize_timeout:g} s")

    def change(self, changed) -> None:
        """Apply ``changed(config, settings) -> (config, settings)`` (a parameter change; it raises
        ConfigError to refuse); registrations under way keep the settings they started with."""
        with self.lock:
            self.shared.config, self.shared.settings = changed(self.shared.config, self.shared.settings)

    # --- the worker ---

    def _next_job(self) -> Job | None:
        if not self.shared.active:
            return None
        maps = self.maps
        job = self._inputs.next_job(self.shared.settings, self.shared.config.features, maps.key,
                                    maps.prepared is not None)
        source = self._inputs.source
        if (self._check_due and maps.prepared is not None and source is not None and source.serial > self._checked
                and not isinstance(job, PrepareMap)):
            job = CheckPose(source)
        if isinstance(job, (Register, CheckPose)) and (self.context.awaits_odometry(job.source.stamp) > 0
                                                       or self.context.awaits_rest() > 0):
            return None
        return job

    def _work(self) -> None:
        while True:
            with self.lock:
                job = self._next_job()
                while job is None and not self.shared.stopping:
                    self.lock.wait(self.context.still_waiting() or 0.5)   # odometry's or a scan's arrival wakes it too
                    job = self._next_job()
                if self.shared.stopping:
                    return
                waited = self.context.end_wait()
                config, settings, hint = self.shared.config, self.shared.settings, self.context.hint
                if isinstance(job, Register):
                    self._inputs.taken(job)
                if isinstance(job, CheckPose):
                    self._check_due, self._checked = False, job.source.serial
            if isinstance(job, PrepareMap):
                self.maps.prepare(job, config)
            elif isinstance(job, CheckPose):
                self._check(job.source, config, settings)
            elif isinstance(job, Register):
                answer = self._register(job, config, settings, hint, waited)
                with self.lock:
                    self._answer = answer
                    if self._relocalizing:  # the watchdog's relocalization: the robot found, or not yet
                        self._relocalizing, self._inputs.relocalize_after = False, None
                        if answer.accepted:
                            self.watchdog.found()
                    self.lock.notify_all()

    def _check(self, src: Cloud, config, settings) -> None:
        """The watchdog's check of the stack's pose at the source's stamp, on the source fused as a
        relocalization fuses it; lost, the next source is registered (Watchdog)."""
        with self.lock:
            pose, why = self.watchdog.pose_for(src.stamp, self.maps.frame, settings.max_pose_age)
            target = self.maps.prepared
        result = None
        if pose is not None and target is None:   # the map was dropped since the check was asked for
            pose, why = None, "no map in use"
        if pose is not None and target is not None:
            T_map_sensor = pose.transform @ settings.base_extrinsic() if settings.base_frame else pose.transform
            source, viewpoints, _ = self.context.source_input(src, settings, config)
            try:
                result = verify(source, target, T_map_sensor, config, **viewpoints)
            except RegistrationError as exc:
                why = f"not checked: {exc}"
        with self.lock:
            if self.shared.stopping:
                return
            check = (self.watchdog.unchecked(why, src.stamp) if result is None or pose is None else
                     self.watchdog.judged(result, src.stamp, pose.stamp, settings.lost_after))
            if check.state == LOST and self._inputs.relocalize_after is None:
                self._relocalizing, self._inputs.relocalize_after = True, src.serial - 1
            self.report.health.watchdog = check
            self._on_check(check)
        if check.state == LOST:
            self.report.logger.error(f"lost: {check.failures} failed checks in a row ({check.reason}); relocalizing")
        elif result is not None and not result.accepted:
            self.report.logger.warning(f"tracked pose suspect: {check.reason}")

    def _register(self, job: Register, config, settings, hint: Hint | None, waited: float = 0.0) -> Answer:
        """Register the source against the pair's target or (map mode) the prepared map, and
        report it; ``waited``: seconds the worker waited for the source's odometry."""
        src = job.source
        target: PreparedCloud | np.ndarray | None
        if settings.mode == "map":
            with self.lock:
                target, target_frame = self.maps.prepared, self.maps.frame
        else:
            assert job.target is not None, "a pair's registration has its target"
            target, target_frame = job.target.points, job.target.frame_id
        if target is None:   # the map was dropped since the job was taken (a lifecycle cleanup)
            return Answer(src.serial, False, "not registered: no map in use")
        try:
            config, source_up = self.context.gravity(config, settings, src)
            region = self.context.region(hint, target_frame)
            source, viewpoints, accumulation = self.context.source_input(src, settings, config)
            if accumulation is not None:
                accumulation["waited_for_odometry_s"] = round(waited, 3)
            result = register(source, target, config, search_region=region, **viewpoints)
        except Exception as exc:  # keep the node alive whatever the input did
            return Answer(src.serial, False, self.report.not_registered(exc))
        with self.lock:
            if self.shared.stopping:  # the node's publishers are going away
                return Answer(src.serial, False, "node stopping")
            self.report.registered(result, accumulation)
            if result.accepted and region is not None and self.context.hint is hint:
                self.context.hint = None  # the robot is found: the hint has done its job
            status = self.report.status(src, job.target, target_frame, settings, config,
                                        {"accumulation": accumulation, "source_up": source_up}, region)
        outcome = self.report.outcome(src, result, target_frame, status, settings, accumulation)
        with self.lock:  # stop() takes the lock before the node's publishers go away
            if self.shared.stopping:
                return Answer(src.serial, False, "node stopping")
            self._on_outcome(outcome)
        return Answer(src.serial, result.accepted, outcome.answer)
