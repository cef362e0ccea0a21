"""Turn raw points into keypoints with FPFH descriptors, once per cloud (core/cloud.py: the
PreparedCloud it makes)."""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from . import kernels
from .cloud import PreparedCloud, SeenCloud, check_viewpoint, clean_points
from .config import FeatureConfig
from .errors import RegistrationError
from .feature_index import FeatureIndex
from .map_view import MapView, trajectory_positions
from .neighbour_grid import NeighbourGrid
from .range_image import nearest_viewpoint
from .shake import seen_views

if TYPE_CHECKING:
    from .gate.judge import Rules
    from .range_image import RangeImage

FPFH_CHUNK = 100_000  # keypoints per FPFH call: bounds its memory (about 100 MB) on a map


GROUND_MIN_POINTS = 100
GROUND_RANSAC_SEED = 0
GROUND_RANSAC_ITERATIONS = 1000
GROUND_RANSAC_SAMPLE = 4000  # points that score each candidate plane


def ground_removed_between(config: FeatureConfig, *clouds: SeenCloud | PreparedCloud) -> bool:
    """Whether the ground leaves the keypoints of a registration between ``clouds``
    (features.remove_ground): only when every one is seen from known sensors. The rings a spinning
    sensor draws on the ground match between two scans at the same place around each sensor; a
    cloud aggregated along a trajectory (a map, a submap: no viewpoint) has them smeared, and there
    the ground holds most of a low or narrow sensor's keypoints and the context of what stands on it."""
    return config.remove_ground and all(c.viewpoints is not None for c in clouds)


def largest_plane(points: np.ndarray, distance: float) -> np.ndarray:
    """Mask of the points within ``distance`` of the largest plane (the ground of a LiDAR scan).

    Its features are ambiguous, and the rings a spinning sensor draws on it match between any
    two scans at the same sensor-relative place, pulling the pose toward 'no motion'. A seeded
    numpy RANSAC: open3d's segment_plane is not repeatable across runs even when seeded.
    """
    rng = np.random.default_rng(GROUND_RANSAC_SEED)
    triples = points[rng.integers(0, len(points), (GROUND_RANSAC_ITERATIONS, 3))]
    normals = np.cross(triples[:, 1] - triples[:, 0], triples[:, 2] - triples[:, 0])
    length = np.linalg.norm(normals, axis=1)
    valid = length > 1e-12
    normals = normals[valid] / length[valid, None]
    offsets = -(normals * triples[valid, 0]).sum(axis=1)
    sample = points[rng.choice(len(points), min(GROUND_RANSAC_SAMPLE, len(points)), replace=False)]
    support = (np.abs(sample @ normals.T + offsets) < distance).sum(axis=0)
    best = int(np.argmax(support))
    inliers = np.abs(points @ normals[best] + offsets[best]) < distance
    # least-squares refit on the inliers: the plane through their centroid, normal of least spread
    centroid = points[inliers].mean(axis=0)
    normal = np.linalg.svd(points[inliers] - centroid, full_matrices=False)[2][2]
    return np.abs((points - centroid) @ normal) < distance


def fpfh(points: np.ndarray, normals: np.ndarray, radius: float, max_nn: int,
         chunk: int = FPFH_CHUNK) -> np.ndarray:
    """(N, 33) float32 FPFH as Open3D computes it (its histograms; neighbourhoods of the max_nn
    nearest points within the radius, the point itself counted), compiled (kernels.fpfh_features)
    on a grid of cells the radius's size, faster than Open3D (which searches a kd-tree per point
    and holds the GIL), the same histograms but where neighbours tie at the cut-off. A point's
    FPFH reads its neighbours' neighbours, so a map goes through in slabs along x of ``chunk``
    points, each with the points within two radii around it, which bounds the memory (about 1 kB
    a point)."""
    def histograms(rows) -> np.ndarray:
        grid = NeighbourGrid(points[rows])
        cells = grid.cells(radius)   # cells no smaller than the radius: their keys suffice
        return kernels.fpfh_features(grid.points, np.ascontiguousarray(normals[rows], dtype=np.float64),
                                     float(radius), int(max_nn), cells.keys, cells.table, cells.starts, cells.order,
                                     cells.ordered).astype(np.float32)

    if len(points) <= chunk:
        return histograms(slice(None))
    order = np.argsort(points[:, 0], kind="stable")
    x = points[order, 0]
    features = np.empty((len(points), 33), dtype=np.float32)
    for start in range(0, len(points), chunk):
        stop = min(start + chunk, len(points))
        first = np.searchsorted(x, x[start] - 2 * radius, side="left")
        last = np.searchsorted(x, x[stop - 1] + 2 * radius, side="right")
        features[order[start:stop]] = histograms(order[first:last])[start - first:stop - first]
    return features


# beyond this share of a cloud's points asking Open3D's kd-tree one at a time, Open3D's own pass over
# the whole cloud (the same normals) is the faster way
TIED_SHARE_FOR_OPEN3D = 0.2


def surface_normals(points: np.ndarray, radius: float, max_nn: int, sensors: np.ndarray | None = None) -> np.ndarray:
    """Open3D's normals (``estimate_normals``, hybrid search) to the bit, computed on every core
    (kernels.surface_normals) where Open3D's run on one and hold the interpreter lock; with
    ``sensors``, each turned to face the nearest of them. A surface is seen from its open side, so
    that is the same side in any cloud that saw it; Open3D leaves the sign to its eigen solver,
    which decides it in the cloud's own axes, so the same surface in two clouds turned apart gets
    opposite signs about as often as not and FPFH's angles, hence its histograms, do not match
    (PCL turns normals toward the viewpoint by default). Where two of a point's neighbours tie in
    distance, Open3D sums them in its kd-tree's order, which only the tree knows: those few points
    ask it."""
    grid = NeighbourGrid(points)
    cells = grid.cells(radius)
    normals, tied = kernels.surface_normals(grid.points, float(radius), int(max_nn), cells.keys, cells.table,
                                            cells.starts, cells.order, cells.ordered)
    asking = np.flatnonzero(tied)
    if len(asking) > TIED_SHARE_FOR_OPEN3D * len(points):   # a lattice's distances all tie
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(grid.points))
        cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=max_nn))
        normals = np.asarray(cloud.normals)
    elif len(asking):
        tree = o3d.geometry.KDTreeFlann(np.ascontiguousarray(grid.points.T))
        for p in asking:
            _, neighbourhood, _ = tree.search_hybrid_vector_3d(grid.points[p], radius, max_nn)
            normals[p] = kernels.normal_of(grid.points, np.asarray(neighbourhood, dtype=np.int64))
    if sensors is None:
        return normals
    toward = nearest_viewpoint(sensors, points) - points
    return np.where(((toward * normals).sum(axis=1) < 0)[:, None], -normals, normals)


def prepare(cloud: SeenCloud, config: FeatureConfig, name: str = "cloud",
            trajectory=None, may_face_sensors: bool = True, rules: Rules | None = None,
            remove_ground: bool | None = None) -> PreparedCloud:
    """Downsample, estimate normals, compute FPFH and L2-normalise the features; with known
    viewpoints also the range image of what each sensor saw (from its raw points), and without
    one the map view (seen from any position; ``trajectory``, the map's sensor poses, adds the
    views from where it was built). With config.normals_toward_sensors and the sensor positions
    known (viewpoints, or the trajectory), the normals face the nearest of them (surface_normals),
    unless ``may_face_sensors`` is false: two clouds' features compare only under one convention,
    and register() prepares a source under its target's. Scans fused along odometry have their views
    read as wide as their own disagreement asks (shake.py, under the judge's ``rules``).
    ``remove_ground``: whether the largest plane is dropped before keypoints; None decides from the
    cloud alone (ground_removed_between)."""
    if cloud.viewpoints is not None:
        for i, vp in enumerate(cloud.viewpoints):
            check_viewpoint(vp, name if len(cloud.parts) == 1 else f"{name} scan {i}")
    parts = [clean_points(p, name if len(cloud.parts) == 1 else f"{name} scan {i}")
             for i, p in enumerate(cloud.parts)]
    points = parts[0] if len(parts) == 1 else np.vstack(parts)
    input_size = len(points)
    down = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points)).voxel_down_sample(config.voxel_size)
    surface = np.asarray(down.points, dtype=np.float64)
    if remove_ground is None:
        remove_ground = ground_removed_between(config, cloud)
    if remove_ground and len(down.points) >= GROUND_MIN_POINTS:
        ground = largest_plane(np.asarray(down.points), config.voxel_size)
        down = down.select_by_index(np.flatnonzero(ground).tolist(), invert=True)
    n = len(down.points)
    if input_size < config.min_points:
        raise RegistrationError(f"{name}: too few points to register ({input_size}; features.min_points="
                                f"{config.min_points} keypoints are needed): is it the whole cloud?")
    if n < config.min_points:
        raise RegistrationError(
            f"{name}: {n} points after downsampling at voxel_size={config.voxel_size:g} m "
            f"(from {input_size}), need at least {config.min_points}; lower features.voxel_size "
            "or send a denser cloud")
    views: tuple[RangeImage, ...] = ()
    map_view, sensors, shake = None, cloud.viewpoints, 0
    if cloud.viewpoints is not None:
        if trajectory is not None:
            raise RegistrationError(f"{name}: a trajectory is for a cloud without viewpoint (a map)")
        views, shake = seen_views(parts, cloud.viewpoints, config.range_image_resolution, config.voxel_size, rules)
    else:
        try:
            positions = None if trajectory is None else trajectory_positions(trajectory)
        except ValueError as exc:
            raise RegistrationError(f"{name} trajectory: {exc}") from None
        map_view = MapView.build(surface, config.voxel_size, config.range_image_resolution, positions)
        sensors = positions
    del parts, points   # a map's raw points: not needed past here, and a copy of them is 45 MB a million
    keypoints = np.asarray(down.points, dtype=np.float64)
    toward = config.normals_toward_sensors and may_face_sensors and sensors is not None and len(sensors) > 0
    normals = surface_normals(keypoints, config.normal_radius, config.normal_max_nn, sensors if toward else None)
    features = fpfh(keypoints, normals, config.fpfh_radius, config.fpfh_max_nn)
    features /= np.linalg.norm(features, axis=1, keepdims=True) + 1e-6
    index = FeatureIndex(features, config.exact_search_limit, config.search_probes,
                         config.search_probes_nearest)
    return PreparedCloud(keypoints, normals, features, cKDTree(keypoints), index, config,
                         input_size, views, map_view, toward, shake, remove_ground)
