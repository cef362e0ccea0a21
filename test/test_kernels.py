"""The compiled kernels give exactly the numpy expressions they replaced, on any thread count."""
import numba
import numpy as np
import pytest
from conftest import dense_power_iteration, dense_soft, load_map_query, random_motion, unpacked
from scipy.spatial.distance import cdist

from regor_ros.core import RegorConfig, kernels, prepare_cloud, register, warm_up
from regor_ros.core.consistency import compatibility, leading_eigenvector, second_order_top_k, seed_consensus


def _problem(seed=0, n=700):
    rng = np.random.default_rng(seed)
    src = rng.uniform(-3, 3, size=(n, 3))
    tgt = src + rng.normal(0, 0.05, size=(n, 3))
    return src, tgt


def _pair_moments(src, tgt):
    """A batch of poses' refinement step on the problem's clouds (grid_pairs_moments)."""
    from regor_ros.core.neighbour_grid import NeighbourGrid
    poses = np.tile(np.eye(4), (3, 1, 1))
    poses[:, :3, 3] = [[0.0, 0.0, 0.0], [0.05, 0.0, 0.0], [0.0, 0.3, 0.1]]
    return NeighbourGrid(tgt).pair_moments(poses, src, 0.12)


def test_landed_counts_is_the_numpy_expression():
    rng = np.random.default_rng(1)
    rotations = np.stack([random_motion(seed)[:3, :3] for seed in range(6)])
    translations = rng.uniform(-0.2, 0.2, size=(6, 3))
    points = rng.uniform(-1, 1, size=(200, 3))
    moved = (points @ np.swapaxes(rotations, 1, 2) + translations[:, None]).astype(np.float32)
    planes = rng.uniform(-1, 1, size=(3, 200, 30)).astype(np.float32)
    threshold2 = np.float32(0.15 ** 2)
    expected = [(sum((planes[c] - m[:, c, None]) ** 2 for c in range(3)).min(axis=1) <= threshold2).sum()
                for m in moved]
    assert min(expected) > 0
    np.testing.assert_array_equal(kernels.landed_counts(rotations, translations, points, planes, threshold2),
                                  expected)


def test_most_length_agreement_is_the_numpy_expression():
    src, tgt = _problem()
    rows = np.arange(0, 700, 3)
    expected = (np.abs(cdist(src[rows], src) - cdist(tgt[rows], tgt)) < 0.05).sum(axis=1).max()
    assert kernels.most_length_agreement(src, tgt, rows, 0.05) == expected


def test_results_do_not_depend_on_the_thread_count():
    src, tgt = _problem(2)
    rows = np.arange(0, 700, 5)
    before = numba.get_num_threads()
    results = []
    try:
        for threads in (1, before):
            numba.set_num_threads(threads)
            compatible = compatibility(src, tgt, 0.1)
            first = second_order_top_k(compatible, rows, 20)
            results.append((compatible.starts, compatible.columns, compatible.values, compatible.hard,
                            compatible.tight, leading_eigenvector(compatible, 10), first,
                            kernels.triangle_scores(src, tgt, 0.1, kernels.threads()),
                            *seed_consensus(first, compatible, 10, 10), *_pair_moments(src, tgt)))
    finally:
        numba.set_num_threads(before)
    for one, many in zip(*results, strict=True):
        np.testing.assert_array_equal(one, many)


def test_verified_candidates_is_the_numpy_expression():
    rng = np.random.default_rng(3)
    moved = rng.uniform(-1, 1, size=(4, 300, 3)).astype(np.float32)   # four poses' moved keypoints
    planes = (moved[0].T[:, :, None] + rng.normal(0, 0.2, size=(3, 300, 20))).astype(np.float32)
    distance = rng.uniform(0, 1, size=(300, 20)).astype(np.float32)
    distance[:, 5] = distance[:, 4]  # ties go to the first
    near2, far2 = np.float32(0.1 ** 2), np.float32(0.15 ** 2)
    verified, got_best, residual = kernels.verified_candidates(moved, planes, distance, near2, far2)
    for pose in range(4):
        e2 = sum((planes[c] - moved[pose, :, c, None]) ** 2 for c in range(3))
        best = np.argmin(distance + 2.0 * (e2 > far2), axis=1)
        np.testing.assert_array_equal(verified[pose], e2.min(axis=1) <= near2)
        np.testing.assert_array_equal(got_best[pose], best)
        np.testing.assert_array_equal(residual[pose], e2[np.arange(300), best])
    assert verified[0].any() and not verified[0].all()


def _numpy_bins(offsets, step, cols):
    ranges = np.linalg.norm(offsets, axis=1)
    keep = ranges > 1e-3
    offsets, ranges = offsets[keep], ranges[keep]
    azimuth = np.arctan2(offsets[:, 1], offsets[:, 0]) + np.pi
    elevation = np.arcsin(np.clip(offsets[:, 2] / ranges, -1.0, 1.0)) + np.pi / 2
    return ranges, np.floor(elevation / step).astype(np.int64) * cols + np.floor(azimuth / step).astype(np.int64) % cols


def test_plane_step_system_is_the_numpy_expression():
    """One point-to-plane step's normal equations, as the refinement wrote them in numpy: the
    pairs within the threshold, arms from their centroid, Cauchy-weighted Jacobian rows."""
    rng = np.random.default_rng(5)
    moved, points = rng.uniform(-1, 1, (500, 3)), rng.uniform(-1, 1, (300, 3))
    normals = rng.normal(size=(300, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    nearest = rng.integers(0, 300, 500)
    distance = rng.uniform(0, 0.2, 500)
    pairs, centre, system, gradient = kernels.plane_step_system(moved, distance, nearest, points, normals, 0.1)
    near = distance < 0.1
    n = normals[nearest[near]]
    arm = moved[near] - moved[near].mean(axis=0)
    residual = np.einsum("ij,ij->i", moved[near] - points[nearest[near]], n)
    jacobian = np.hstack([np.cross(arm, n), n])
    weighted = jacobian / (1 + (residual / 0.1) ** 2)[:, None]
    assert pairs == near.sum()
    np.testing.assert_allclose(centre, moved[near].mean(axis=0), atol=1e-12)
    np.testing.assert_allclose(system, weighted.T @ jacobian, atol=1e-10)
    np.testing.assert_allclose(gradient, weighted.T @ residual, atol=1e-10)


def test_spherical_bins_and_free_space_classes_are_the_numpy_expressions():
    rng = np.random.default_rng(6)
    points = rng.normal(0, 20, size=(20_000, 3))
    points[:5] = 0.0  # at the viewpoint: no direction, dropped / never seen
    step, cols = np.radians(1.0), 360
    ranges, index = kernels.spherical_bins(points, step, cols, 1e-3)
    expected_ranges, expected_index = _numpy_bins(points, step, cols)
    np.testing.assert_array_equal(ranges, expected_ranges)
    np.testing.assert_array_equal(index, expected_index)

    depth = rng.uniform(0, 40, size=(181, 360)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.3] = 0.0  # unknown bins
    slack = rng.uniform(0, 0.5, len(points))
    seen, inside = kernels.free_space_classes(points, np.zeros(3), depth, step, 1e-3, 0.15, 0.02, slack)
    usable = np.linalg.norm(points, axis=1) > 1e-3
    d = depth.ravel()[expected_index]
    np.testing.assert_array_equal(seen[usable], d > 0)
    np.testing.assert_array_equal(inside[usable], (d > 0) & (expected_ranges < d - 0.15 - 0.02 * d - slack[usable]))
    assert not seen[~usable].any() and not inside[~usable].any()


def _filtered_free_depth(index, ranges, width, rows, cols, blur):
    """The range image as RangeImage.build wrote it before the kernel: a minimum and a maximum
    filter per footprint width, the minimum ``blur`` bins wider (azimuth wraps, elevation takes the
    nearest row)."""
    from scipy.ndimage import maximum_filter, minimum_filter
    free = np.full((rows, cols), np.inf, dtype=np.float32)
    covered = np.zeros((rows, cols), dtype=bool)
    for w in np.unique(width):
        nearest = np.full(rows * cols, np.inf, dtype=np.float32)
        np.minimum.at(nearest, index[width == w], ranges[width == w])
        nearest = nearest.reshape(rows, cols)
        covered |= maximum_filter(np.isfinite(nearest), size=2 * w - 1, mode=("nearest", "wrap"))
        free = np.minimum(free, minimum_filter(nearest, size=2 * (w + blur) + 1, mode=("nearest", "wrap")))
    free[~covered] = 0.0
    return free


def test_splatted_free_depth_is_the_filtered_image():
    """Returns near the poles and across the azimuth seam, footprints of 1 to 8 bins, read as they
    are and blurred by a shaking sequence's bins."""
    rng = np.random.default_rng(7)
    rows, cols = 181, 360
    n = 5000
    index = np.concatenate([rng.integers(0, rows * cols, n - 40), rng.integers(0, 3 * cols, 20),
                            (rng.integers(0, rows, 20) * cols + rng.choice([0, 1, cols - 2, cols - 1], 20))])
    ranges = rng.uniform(0.5, 80, n).astype(np.float32)
    width = rng.choice(np.arange(1, 9), n, p=[0.7, 0.1, 0.05, 0.05, 0.03, 0.03, 0.02, 0.02]).astype(np.int64)
    for blur in (0, 3):
        np.testing.assert_array_equal(kernels.splatted_free_depth(index, ranges, width, rows, cols, blur),
                                      _filtered_free_depth(index, ranges, width, rows, cols, blur))


def test_within_any_is_the_ball_query():
    """The points within each centre's radius, as the union of scipy's ball queries."""
    from scipy.spatial import cKDTree
    rng = np.random.default_rng(8)
    points = rng.uniform(-50, 50, size=(30_000, 3))
    centres, radii = rng.uniform(-40, 40, size=(3, 3)), np.array([5.0, 12.5, 20.0])
    expected = np.zeros(len(points), bool)
    for centre, radius in zip(centres, radii, strict=True):
        expected[cKDTree(points).query_ball_point(centre, radius)] = True
    assert 100 < expected.sum() < len(points)
    np.testing.assert_array_equal(kernels.within_any(points, centres, radii), expected)


def _compiled() -> dict:
    return {name: len(kernel.signatures) for name, kernel in vars(kernels).items()
            if isinstance(kernel, numba.core.registry.CPUDispatcher)}


def test_registrations_after_warm_up_compile_nothing(kitchen_pair):
    """warm_up compiles every type a registration passes, so none compiles on the first one:
    scan to scan (free space from both sensors), and a scan against a map (the map's views) under
    a gravity prior (the height condition)."""
    warm_up()
    compiled = _compiled()
    src, tgt, _, _ = kitchen_pair
    register(src, tgt, RegorConfig.preset("indoor"))
    scan, cloud, _ = load_map_query("scaloam_mulran_kaist03", "scan_000005")
    config = RegorConfig.preset("outdoor").replace({"gravity.source_up": "0 0 1", "gravity.target_up": "0 0 1"})
    register(scan, prepare_cloud(cloud, config, "map"), config)
    assert _compiled() == compiled


def _blas_threads():
    """{library path: threads} of the BLAS libraries loaded."""
    from threadpoolctl import threadpool_info
    return {lib["filepath"]: lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"}


def test_numpy_blas_runs_on_one_thread_during_registrations_and_is_restored():
    import faiss  # noqa: F401  (its BLAS copy is loaded, as in any registration)
    before = _blas_threads()
    numpy_blas = [path for path in before if "faiss" not in path.lower()]
    assert numpy_blas
    with kernels.blas_on_one_thread():
        with kernels.blas_on_one_thread():  # a second registration on another thread
            pass
        inside = _blas_threads()  # still limited: the first has not finished
    assert all(inside[path] == 1 for path in numpy_blas)
    assert all(inside[path] == before[path] for path in before if path not in numpy_blas)  # FAISS's own
    assert _blas_threads() == before


def _seed_consensus_numpy(first, hard, soft, k2, iterations):
    """SC2-PCR++'s second stage and local spectral weights as numpy expressions (what
    seed_consensus replaced), on dense hard and soft matrices."""
    from regor_ros.core.consistency import top_k_stable
    hard_first = hard[first[:, :, None], first[:, None, :]].astype(np.float32)
    score = np.einsum("sm,smj->sj", hard_first[:, 0, :], hard_first)
    second = np.take_along_axis(first, top_k_stable(score, k2), axis=1)
    local = soft[second[:, :, None], second[:, None, :]].copy()
    diag = np.arange(k2)
    local[:, diag, diag] = 0.0
    return second, dense_power_iteration(local, iterations)


@pytest.mark.parametrize("k1, k2, iterations", [(20, 10, 10), (40, 30, 10), (12, 12, 1), (20, 10, 0)])
def test_seed_consensus_is_the_numpy_expression(k1, k2, iterations):
    """The members exactly; the weights up to float32 rounding (its sums run in another order),
    stopped at the same power iteration for the whole batch."""
    src, tgt = _problem(3)
    tgt[::3] = np.random.default_rng(4).uniform(-3, 3, size=tgt[::3].shape)   # outliers: sets differ
    compatible = compatibility(src, tgt, 0.1)
    first = second_order_top_k(compatible, np.arange(0, 700, 2), k1)
    second, weights = seed_consensus(first, compatible, k2, iterations)
    expected_second, expected_weights = _seed_consensus_numpy(first, unpacked(compatible.hard, len(src)),
                                                              dense_soft(compatible), k2, iterations)
    np.testing.assert_array_equal(second, expected_second)
    np.testing.assert_allclose(weights, expected_weights, rtol=0, atol=1e-6)
    assert weights.dtype == np.float32
