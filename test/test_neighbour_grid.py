"""The refinements' nearest-keypoint search answers as a kd-tree does, whatever the cloud."""
import numpy as np
import pytest
from scipy.spatial import cKDTree

from regor_ros.core.neighbour_grid import NeighbourGrid


def _as_kd_tree(points, queries, threshold, dense=True):
    """The grid answers as the kd-tree, its empty cells flagged densely or (a wide cloud) not:
    the nearest point within the threshold, and how many lie within it."""
    grid = NeighbourGrid(points)
    grid_distance, grid_index = grid.nearest_within(queries, threshold)
    assert (len(grid.cells(threshold).occupied) > 0) == dense
    tree = cKDTree(points)
    np.testing.assert_array_equal(grid.count_within(queries, threshold),
                                  tree.query_ball_point(queries, threshold, return_length=True))
    tree_distance, tree_index = tree.query(queries, distance_upper_bound=threshold)
    found = np.isfinite(tree_distance)
    np.testing.assert_array_equal(np.isfinite(grid_distance), found)
    np.testing.assert_array_equal(grid_distance[found], tree_distance[found])
    np.testing.assert_array_equal(grid_index[found], tree_index[found])
    assert (grid_index[~found] == len(points)).all()
    return found


@pytest.mark.parametrize("threshold", [0.05, 0.1, 0.37, 1.2])
def test_nearest_within_a_threshold_is_the_kd_trees(threshold):
    rng = np.random.default_rng(3)
    points = rng.random((4000, 3)) * [6.0, 4.0, 2.0] - 1.0
    queries = rng.random((3000, 3)) * [8.0, 6.0, 4.0] - 2.0   # some far outside the cloud
    found = _as_kd_tree(points, queries, threshold)
    assert 0 < found.sum() < len(queries)


def test_a_cloud_too_wide_for_cells_of_the_threshold_still_answers():
    """Cells are enlarged when the cloud spans more of them than a key packs (a map in UTM-sized
    coordinates); each then holds more points."""
    rng = np.random.default_rng(4)
    points = np.vstack([rng.random((500, 3)), rng.random((500, 3)) + [2.0e5, 2.0e5, 0.0]])
    queries = np.vstack([rng.random((300, 3)), rng.random((300, 3)) + [2.0e5, 2.0e5, 0.0]])
    assert _as_kd_tree(points, queries, 0.05, dense=False).sum() > 100


def test_a_threshold_asked_again_reuses_its_grid_and_an_empty_cloud_finds_nothing():
    grid = NeighbourGrid(np.random.default_rng(5).random((50, 3)))
    grid.nearest_within(np.zeros((2, 3)), 0.2)
    built = grid._grids[0.2]
    grid.nearest_within(np.ones((2, 3)), 0.2)
    assert grid._grids[0.2] is built
    distance, index = NeighbourGrid(np.zeros((0, 3))).nearest_within(np.zeros((2, 3)), 0.2)
    assert np.isinf(distance).all() and (index == 0).all()
    assert (NeighbourGrid(np.zeros((0, 3))).count_within(np.zeros((2, 3)), 0.2) == 0).all()
    moments = NeighbourGrid(np.zeros((0, 3))).pair_moments(np.tile(np.eye(4), (3, 1, 1)), np.zeros((2, 3)), 0.2)
    assert moments.distance.shape == (3, 2) and np.isinf(moments.distance).all() and (moments.paired == 0).all()


def test_a_map_wide_grid_flags_its_cells_a_bit_each():
    """A map's grid at a refinement's threshold spans tens of millions of cells: one bit each
    keeps the flags small (here 53 M cells in 6.6 MB) and the answers the kd-tree's."""
    rng = np.random.default_rng(6)
    points = rng.random((20000, 3)) * [700.0, 650.0, 25.0]
    queries = np.vstack([points[:2000] + rng.normal(scale=0.3, size=(2000, 3)), rng.random((2000, 3)) * 700.0])
    assert _as_kd_tree(points, queries, 0.6).sum() > 1000
    assert NeighbourGrid(points).cells(0.6).occupied.nbytes < 7e6


def test_a_grid_too_wide_for_a_bit_per_cell_flags_blocks_of_cells():
    """A map a few kilometres wide at the finest threshold spans billions of cells: a bit then
    flags a block of cells, and the answers stay the kd-tree's, near its surfaces and off them."""
    rng = np.random.default_rng(7)
    ground = rng.random((20000, 3)) * [3000.0, 2000.0, 0.3]
    wall = rng.random((5000, 3)) * [0.3, 40.0, 20.0] + [1500.0, 1000.0, 0.0]
    points = np.vstack([ground, wall])
    queries = np.vstack([points[::5] + rng.normal(scale=0.2, size=(5000, 3)), rng.random((2000, 3)) * 3000.0])
    cells = NeighbourGrid(points).cells(0.3)
    assert cells.shift > 0 and cells.occupied.nbytes <= (1 << 28) // 8
    assert _as_kd_tree(points, queries, 0.3).sum() > 1000
