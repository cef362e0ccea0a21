"""A prepared map saved to disk, so that a robot's restart does not prepare its map again.

Preparing a large map takes seconds (doc/benchmarks.md): normals, FPFH, and the k-means training of its
feature index. A cache file holds what preparation computed: keypoints, normals, features, the
trained index (its cell centres and each keypoint's cell), and the map view's surface and
trajectory. It is keyed by a digest of the map's content, its trajectory and every feature
setting, so a changed file or setting never reuses it. The keypoints' kd-tree is rebuilt on load,
beside the index's lists (filed again from the features).
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from ..core.cloud import PreparedCloud
from ..core.config import FeatureConfig
from ..core.feature_index import FeatureIndex
from ..core.map_view import MapView

# raise when the saved arrays or their meaning change (3: normals face the sensors; 4: a map keeps its
# ground; 5: the index's cells trained in two levels; 6: a map's normals compiled; 7: in Open3D's arithmetic)
CACHE_VERSION = 7


class CacheError(Exception):
    """A cache file that cannot be used: stale (another map or settings) or unreadable."""


def map_key(map_digest: str, trajectory_digest: str, config: FeatureConfig) -> str:
    """What a cached map must match: the map's and trajectory's content and the feature settings."""
    text = json.dumps({"version": CACHE_VERSION, "map": map_digest, "trajectory": trajectory_digest,
                       "features": dataclasses.asdict(config)}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


def file_digest(path) -> str:
    """SHA-256 of a file's bytes ("" for no file)."""
    if not path:
        return ""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 22), b""):
            digest.update(block)
    return digest.hexdigest()


def save_map(prepared: PreparedCloud, path: Path, key: str) -> int:
    """Write the prepared map (one with a map view) atomically; returns the file's size in bytes."""
    if prepared.map_view is None:
        raise ValueError("only a cloud without viewpoint (a map) is cached")
    view = prepared.map_view
    centres, cells = prepared.index.saved()
    path = Path(path)
    partial = path.with_name(path.name + f".{os.getpid()}.partial")
    with open(partial, "wb") as f:
        np.savez(f, key=np.array(key), points=prepared.points, normals=prepared.normals,
                 features=prepared.features, index_centres=centres, index_cells=cells,
                 input_size=np.array(prepared.input_size), surface=view.surface,
                 footprint=np.array(view.footprint), resolution_deg=np.array(view.resolution_deg),
                 trajectory=view.trajectory, normals_toward_sensors=np.array(prepared.normals_toward_sensors))
    os.replace(partial, path)
    return path.stat().st_size


def load_map(path: Path, key: str, config: FeatureConfig) -> PreparedCloud:
    """The prepared map saved under ``key``; CacheError when the file is for another key or
    cannot be read."""
    try:
        with np.load(path, allow_pickle=False) as saved:
            if str(saved["key"]) != key:
                raise CacheError(f"{path} is for another map file or other feature settings")
            points, surface, trajectory = saved["points"], saved["surface"], saved["trajectory"]
            # the kd-tree builds without the GIL: beside the rest
            with ThreadPoolExecutor(1) as pool:
                tree = pool.submit(cKDTree, points)
                features = saved["features"]
                index = FeatureIndex(features, config.exact_search_limit, config.search_probes,
                                     config.search_probes_nearest,
                                     saved=(saved["index_centres"], saved["index_cells"]))
                normals = saved["normals"]
                point_tree = tree.result()
            view = MapView(surface, float(saved["footprint"]), float(saved["resolution_deg"]),
                           trajectory, cKDTree(trajectory) if len(trajectory) else None)
            return PreparedCloud(points, normals, features, point_tree, index, config,
                                 int(saved["input_size"]), (), view, bool(saved["normals_toward_sensors"]))
    except CacheError:
        raise
    except Exception as exc:  # a truncated or foreign file: any reader error means "rebuild"
        raise CacheError(f"{path} is unreadable ({type(exc).__name__}: {exc})") from None
