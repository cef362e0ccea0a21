"""What a batch worker does with one pair: register it (or verify the pose the row gives), with each
cloud prepared once per process.

Candidate lists share clouds (a scan is checked against each place recognition proposes for it),
and preparing a cloud (voxel grid, normals, FPFH) is a fair share of a registration. Each worker
process keeps the clouds it prepared most recently and reuses them; register() gives the same
pose for a prepared cloud as for its raw points. The one exception is acceptance.retries: a retry
re-grids the raw source, so with retries the source is passed raw (prepared per pair).
"""
from __future__ import annotations

import logging
import os
import socket
import threading
import time
from collections import OrderedDict
from typing import Any

import numba
import numpy as np
from distributed.core import Status
from distributed.diagnostics.plugin import WorkerPlugin

from ..core import PreparedCloud, RegorConfig, for_clouds_seen_from, prepare_cloud, register, verify
from ..io.cloud_io import read_cloud
from .batch_list import PairRow


class PreparedClouds:
    """The ``capacity`` clouds this process prepared last, by file, its state on disk, viewpoint
    and feature settings (a rewritten file or other settings is prepared again)."""

    def __init__(self, capacity: int):
        self.capacity = capacity
        self._clouds: OrderedDict[tuple, PreparedCloud] = OrderedDict()
        self._lock = threading.Lock()  # a worker may run pairs in several threads

    @staticmethod
    def key(path, viewpoint, config: RegorConfig) -> tuple:
        stat = os.stat(path)  # FileNotFoundError for a missing file: the row's error
        return str(path), stat.st_size, stat.st_mtime_ns, viewpoint, repr(config.features)

    def get(self, path, viewpoint, config: RegorConfig, name: str):
        """(the prepared cloud, whether it was reused)."""
        key = self.key(path, viewpoint, config)
        with self._lock:
            if key in self._clouds:
                self._clouds.move_to_end(key)
                return self._clouds[key], True
        cloud = prepare_cloud(read_cloud(path), config, name, viewpoint=viewpoint)
        with self._lock:
            self._clouds[key] = cloud
            while len(self._clouds) > self.capacity:
                self._clouds.popitem(last=False)
        return cloud, False


_clouds: PreparedClouds | None = None  # this process's, made by the first pair it registers


class QuietShutdown(WorkerPlugin):
    """A worker plugin: a worker that is closing does not log its failed heartbeat. Closing the
    local cluster, a worker's heartbeat already in flight can meet the connections the worker is
    closing itself (often with both cores busy; dask/distributed#7105), and distributed
    logs that at ERROR with two tracebacks: noise after a finished batch that looks like a failure.
    A running worker's failed heartbeat is still logged."""

    name = "regor-quiet-shutdown"

    def setup(self, worker) -> None:
        def unless_closing(record: logging.LogRecord) -> bool:
            return not (worker.status in (Status.closing, Status.closed)
                        and record.getMessage().startswith("Failed to communicate with scheduler during heartbeat"))
        logging.getLogger("distributed.worker").addFilter(unless_closing)


def _process_clouds(capacity: int) -> PreparedClouds:
    global _clouds
    if _clouds is None or _clouds.capacity != capacity:
        _clouds = PreparedClouds(capacity)
    return _clouds


def row_identity(row: PairRow) -> dict:
    """The fields that say which pair an output row is for."""
    return {"id": row.id, "source": row.source, "target": row.target, "preset": row.preset}


def result_row(result) -> dict:
    """A registration's output row: the pose, its covariance, the verdict and the gate's figures."""
    return {"transform": result.transform.tolist(), "covariance": result.covariance.tolist(),
            **result.summary().as_json()}


def register_row(row: PairRow, overrides: dict[str, object], cache_capacity: int,
                 threads: int | None = None) -> dict:
    """The output row of one pair; any failure becomes the row's ``error``, never an exception.
    ``threads``: the compiled kernels' threads for this task (None: as many as the process has)."""
    start = time.perf_counter()
    if threads:
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))  # type: ignore[attr-defined]
    out = {**row_identity(row), "worker": f"{socket.gethostname()}:{os.getpid()}"}
    try:
        if row.error:
            raise ValueError(row.error)
        config = for_clouds_seen_from(RegorConfig.preset(row.preset).replace(overrides),
                                      row.source_viewpoint, row.target_viewpoint)
        clouds = _process_clouds(cache_capacity)
        target, target_reused = clouds.get(row.target_path, row.target_viewpoint, config, "target")
        if config.acceptance.retries:
            source, source_reused = read_cloud(row.source_path), False
            kwargs: dict[str, Any] = {"source_viewpoint": row.source_viewpoint}
        else:
            (source, source_reused), kwargs = clouds.get(row.source_path, row.source_viewpoint, config, "source"), {}
        if row.pose is not None:   # a candidate that comes with its pose: verified, not searched
            given = np.array(row.pose).reshape(4, 4)
            checked = verify(source, target, given, config, **kwargs)
            out.update({"transform": checked.transform.tolist(), "given": given.tolist(),
                        **checked.summary().as_json()})
        else:
            out.update(result_row(register(source, target, config, **kwargs)))
        out.update(reused=int(source_reused) + int(target_reused), error="")
    except FileNotFoundError as exc:
        out.update(accepted=False, error=f"{exc.filename}: no such file")
    except (ValueError, OSError, MemoryError) as exc:  # RegistrationError and ConfigError are ValueErrors
        out.update(accepted=False, error=str(exc) or type(exc).__name__)
    out["seconds"] = time.perf_counter() - start
    return out

