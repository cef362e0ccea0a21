"""The map the node registers against, without ROS: loaded one way whoever asks (configure, the
load_map service, the worker after a feature setting changed or a target message arrived), and
changed only when the new one is ready; the one in use stays when a new one fails."""
from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from pathlib import Path
from urllib.parse import parse_qs, urlparse

from ..core import PreparedCloud, RegistrationError, prepare_cloud
from ..io.map_file import load_map_file
from .inputs import MapKey, PrepareMap
from .report import Report
from .shared import Shared


class MapSlot:
    """The prepared map in use, its frame and what it was made from; ``publish`` sends a map out
    (for RViz) when it is put in use while the node is active."""

    def __init__(self, shared: Shared, report: Report, publish: Callable[[PreparedCloud, str], None]):
        self.shared, self.report, self.publish = shared, report, publish
        self.clear()

    def clear(self) -> None:
        """No map (the caller holds the lock)."""
        self.prepared: PreparedCloud | None = None
        self.frame = ""
        self.key: MapKey | None = None

    def use_url(self, map_url: str) -> None:
        """Load the map a nav_msgs/LoadMap request names: its path or file:// URL, with
        ``?trajectory=PATH`` for its TUM trajectory. FileNotFoundError (and the map in use stays)
        when a file is not there, RegistrationError when it is not usable."""
        url = urlparse(map_url)
        path = url.path if url.scheme in ("", "file") else ""
        trajectory = parse_qs(url.query).get("trajectory", [""])[0]
        missing = [p for p in (path, trajectory) if p and not Path(p).expanduser().is_file()]
        if not path or missing:
            raise FileNotFoundError(missing[0] if missing else repr(map_url))
        self.use_file(path, trajectory)

    def use_file(self, path: str, trajectory: str) -> None:
        """Load (or prepare and cache) a map file and register against it from now on; the map in
        use stays until then, and stays when this raises RegistrationError (with the reason)."""
        config, settings = self.shared.snapshot()
        key = MapKey.of_file(path, trajectory, config.features)

        def load():
            loaded = load_map_file(path, config, trajectory or None, settings.map_cache,
                                   settings.map_cache_dir, warn=self.report.logger.warning)
            return loaded.prepared, loaded.info

        prepared = self._put_in_use(load, key, settings.map_frame, (path, trajectory))
        with self.shared.lock:  # for RViz: the map as the node uses it (not while its publishers go away)
            if prepared is not None and self.shared.active and not self.shared.stopping:
                self.publish(prepared, settings.map_frame)

    def prepare(self, job: PrepareMap, config) -> None:
        """The worker's job: prepare the map once per message or file (and feature settings);
        queries wait meanwhile. A map that cannot be used is bad input: no map, and not prepared
        again until its source or the feature settings change."""
        key = job.key
        try:
            if key.file:
                self.use_file(key.file, key.trajectory)
            else:
                target = job.target
                assert target is not None, "a map that is no file comes as a target message"
                self._put_in_use(lambda: (prepare_cloud(target.points, config, "target",
                                                        viewpoint=key.viewpoint), {}),
                                 key, target.frame_id)
        except RegistrationError as exc:
            with self.shared.lock:
                if not self.shared.stopping:
                    self.prepared, self.key, self.frame = None, key, ""
            self.report.health.last_error = f"map not usable: {exc}"
            self.report.bad_input(f"map skipped: {exc}")

    def _put_in_use(self, prepare, key: MapKey, frame: str,
                    file: tuple[str, str] | None = None) -> PreparedCloud | None:
        """Run ``prepare`` (-> prepared map, info) and make its map the one registered against; a
        map ``file`` (path, trajectory) becomes the settings' map file in the same step (other
        settings changed meanwhile are kept). None when the node stopped meanwhile."""
        health = self.report.health
        health.preparing_map = True
        start = time.perf_counter()
        try:
            prepared, info = prepare()
        finally:
            health.preparing_map = False
        seconds = time.perf_counter() - start
        with self.shared.lock:
            if self.shared.stopping:  # the node's publishers are going away
                return None
            self.prepared, self.key, self.frame = prepared, key, frame
            if file is not None:
                self.shared.settings = dataclasses.replace(self.shared.settings, map_file=file[0],
                                                           map_trajectory_file=file[1])
                health.map_from_file = True
            self.report.stats["map_preparations"] += 1
            health.last_error = ""
            health.map_info = {
                "map_points": prepared.input_size, "map_keypoints": len(prepared),
                "map_exact_search": prepared.index.exact, **info,
                "map_preparation_seconds": round(seconds, 3)}
            self.shared.lock.notify_all()
        cache = f", cache {info['map_cache']}" if info.get("map_cache") else ""
        self.report.logger.info(f"map prepared: {prepared.input_size} points, {len(prepared)} keypoints "
                                f"in {seconds:.1f} s{cache}")
        return prepared
