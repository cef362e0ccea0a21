"""Compiled inner loops of the consensus steps, the refinements, the free-space check, the feature
search and FPFH (numba), where numpy did the arithmetic in a wider form than the method needs, FAISS read
memory in an order that made it wait or searched the same products more than once, or Open3D
searched a kd-tree per point holding the GIL.

Each consensus kernel gives exactly what the numpy expression it replaced gave (the tests hold
them to those expressions): the same float32 rounding of the length residual, integer counts, ties
broken by index; the seeds' local spectral weights and the refinement's moments are the same sums
in another order (the last bits differ). The feature search gives the similarities of a numpy matrix product; FAISS,
which it replaced, sums in another order (the last bit may differ). Nothing depends on the
number of threads. FPFH gives Open3D's histograms (the tests hold it to them) but for the order
of a sum's terms and which of the neighbours tied at the max_nn-th distance are kept; the normals
are Open3D's to the bit, its arithmetic step for step (features.surface_normals asks Open3D's
kd-tree for the order of tied neighbours where it matters).
Compiled code is cached on disk (``cache=True``); ``warm_up`` compiles or loads every kernel, so a
node pays that when it starts, not on its first relocalization.

They live by what they compute: consensus.py, candidates.py (the initial stage's poses),
free_space.py, feature_search.py, grid.py (neighbours and the refinements' sums) and fpfh.py; the
threads they run on in threads.py (OpenMP first, and numpy's BLAS kept off the cores while a
registration runs: ``blas_on_one_thread``), helpers two domains share in common.py.
"""
from __future__ import annotations

import numpy as np

from .candidates import landed_counts, most_length_agreement, verified_candidates
from .consensus import (
    compatibility_matrices,
    generalized_mutual_pairs,
    region_agreement,
    second_order_top_k,
    seed_consensus,
    sparse_leading_eigenvector,
    triangle_scores,
)
from .feature_search import FLOOR_STRIDE, cell_top_k, flat_search
from .fpfh import fpfh_features, normal_of, surface_normals
from .free_space import free_space_classes, spherical_bins, splatted_free_depth, within_any
from .grid import (
    GRID_AXIS_BITS,
    fixed_pairs_moments,
    flag_bits,
    greedy_apart,
    grid_count_within,
    grid_keys,
    grid_nearest,
    grid_pairs_moments,
    grid_table,
    plane_step_system,
    pooled_counts,
)
from .threads import blas_on_one_thread, threads

__all__ = [  # what the core's modules call as kernels.<name>
    "FLOOR_STRIDE",
    "GRID_AXIS_BITS",
    "blas_on_one_thread",
    "cell_top_k",
    "compatibility_matrices",
    "fixed_pairs_moments",
    "flag_bits",
    "flat_search",
    "fpfh_features",
    "free_space_classes",
    "generalized_mutual_pairs",
    "greedy_apart",
    "grid_count_within",
    "grid_keys",
    "grid_nearest",
    "grid_pairs_moments",
    "grid_table",
    "landed_counts",
    "most_length_agreement",
    "normal_of",
    "plane_step_system",
    "pooled_counts",
    "region_agreement",
    "second_order_top_k",
    "seed_consensus",
    "sparse_leading_eigenvector",
    "spherical_bins",
    "splatted_free_depth",
    "surface_normals",
    "threads",
    "triangle_scores",
    "verified_candidates",
    "warm_up",
    "within_any",
]


def warm_up() -> None:
    """Compile (or load from the disk cache) every kernel for the types the pipeline passes,
    under the BLAS limit a registration runs them under (cell_top_k's products would otherwise
    start scipy's OpenBLAS threads, which took the node's cores under load)."""
    with blas_on_one_thread():
        points = np.random.default_rng(0).random((8, 3))
        compatibility_matrices(points, points, 0.1, np.zeros(8), 0.0, False)
        starts, columns, soft, hard, tight = compatibility_matrices(points, points, 0.1, np.zeros(8), 0.0, True)
        sparse_leading_eigenvector(starts, columns, soft, 2)
        second_order_top_k(tight, starts, columns, np.arange(3, dtype=np.int64), 2)
        seed_consensus(np.zeros((2, 3), np.int64), hard, points, points, 0.1, np.zeros(8), 0.0, True, 2, 2)
        triangle_scores(points, points, 0.1, 2)
        generalized_mutual_pairs(np.random.default_rng(0).random((2, 4, 5)).astype(np.float32), 3)
        landed_counts(np.zeros((2, 3, 3)), np.zeros((2, 3)), np.zeros((8, 3)), np.zeros((3, 8, 4), np.float32),
                      np.float32(0.01))
        verified_candidates(np.zeros((2, 8, 3), np.float32), np.zeros((3, 8, 4), np.float32),
                            np.zeros((8, 4), np.float32), np.float32(0.01), np.float32(0.02))
        most_length_agreement(points, points, np.arange(3, dtype=np.int64), 0.05)
        fixed_pairs_moments(np.eye(3)[None], np.zeros((1, 3)), points, points, 0.1)
        plane_step_system(points, np.zeros(8), np.zeros(8, np.int64), points, points, 0.1)
        region_agreement(points.reshape(2, 4, 3), points.reshape(2, 4, 3), np.ones((2, 4), np.bool_), 0.05)
        spherical_bins(points, 0.01, 8, 1e-3)
        free_space_classes(points, np.zeros(3), np.ones((4, 8), np.float32), 0.01, 1e-3, 0.1, 0.01, np.zeros(8))
        splatted_free_depth(np.arange(3, dtype=np.int64), np.ones(3, np.float32), np.ones(3, np.int64), 2, 4, 0)
        within_any(points, points[:2], np.ones(2))
        greedy_apart(points[:2].copy(), np.zeros((2, 3), np.int64), np.arange(2, dtype=np.int64), 0.1)
        pooled_counts(np.arange(3, dtype=np.int64), np.arange(4, dtype=np.int64), np.arange(2, dtype=np.int64))
        keys = np.unique(grid_keys(np.zeros((2, 3), np.int64)))
        grid = (keys, grid_table(keys), np.array([0, 2], np.int64), np.arange(2, dtype=np.int64), points[:2].copy(),
                flag_bits(np.zeros(1, np.int64), 1), np.ones(3, np.int64), 0)
        grid_nearest(points, np.zeros(3), 0.1, 0.1, *grid)
        grid_count_within(points, np.zeros(3), 0.1, 0.1, *grid)
        grid_pairs_moments(np.eye(3)[None], np.zeros((1, 3)), points, points[:2].copy(), np.zeros(3), 0.1, 0.1, *grid)
        flat_search(np.zeros((2, 4), np.float32), np.zeros((3, 4), np.float32), np.array([0, -1], np.int64), 2, True, 2)
        cell_top_k(np.zeros((2, 4), np.float32), np.zeros((2, 1), np.int64), np.zeros((3, 4), np.float32),
                   np.array([0, 3], np.int64), 2, 2)
        normals = np.tile([0.0, 0.0, 1.0], (2, 1))
        fpfh_features(points[:2].copy(), normals, 0.1, 3, keys, grid_table(keys), np.array([0, 2], np.int64),
                      np.arange(2, dtype=np.int64), points[:2].copy())
        surface_normals(points[:2].copy(), 0.1, 3, keys, grid_table(keys), np.array([0, 2], np.int64),
                        np.arange(2, dtype=np.int64), points[:2].copy())
        normal_of(points[:2].copy(), np.arange(2, dtype=np.int64))
