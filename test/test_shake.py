"""A shaking sensor's fused scans (core/shake.py): their free space is read as wide as they disagree
with each other, so a right pose passes the check while a wrong one still fails; a steady sequence
is read as it always was."""
import numpy as np
from scipy.spatial.transform import Rotation

from regor_ros.bench.datasets import shaken
from regor_ros.core import RegorConfig, prepare_cloud, register
from regor_ros.core.estimate import inliers_at, resolution_uncertainty
from regor_ros.core.features import prepare
from regor_ros.core.gate.visibility import free_space_figures
from regor_ros.core.geometry import to_matrix

OUTDOOR = RegorConfig.preset("outdoor")
SHAKE_DEG = 3.0


def worst_at(T, fused, target):
    """The free-space figure the gate judges ``T`` on, with a right pose's resolution allowance."""
    pairs = inliers_at(T, fused.points, target.neighbours, OUTDOOR.estimation.inlier_threshold)
    uncertainty = resolution_uncertainty(T, fused.points[pairs.source_index], OUTDOOR.features.voxel_size)
    return free_space_figures(T, fused, target, OUTDOOR.acceptance, uncertainty=uncertainty).worst_free_space


def test_a_shaky_sequences_right_pose_passes_free_space_and_a_turned_one_does_not(avia_map):
    """scan_000237 and the four scans before it, shaken by 3 deg: read as a steady sequence's, 5 %
    of the scans lie in the map's free space at the true pose (the check allows 3 %); read as wide
    as the scans disagree with each other, the true pose passes, and the pose turned by 90 deg
    still fails."""
    target, queries = avia_map
    query = queries["scan_000237"]
    sequence = shaken(query.history, SHAKE_DEG, np.random.default_rng(4))
    fused = prepare_cloud(sequence, OUTDOOR, "scans")
    assert fused.shake_bins >= 1
    limit = OUTDOOR.acceptance.max_free_space_violation
    assert worst_at(query.truth, fused, target) <= limit
    assert register(sequence, target, OUTDOOR).visibility.shake_bins == fused.shake_bins
    as_if_steady = prepare(sequence.fused(), OUTDOOR.features, "scans")
    assert as_if_steady.shake_bins == 0 and worst_at(query.truth, as_if_steady, target) > limit
    turned = query.truth @ to_matrix(Rotation.from_euler("z", 90.0, degrees=True).as_matrix(), np.zeros(3))
    assert worst_at(turned, fused, target) > 0.1


def test_a_steady_sequence_is_read_as_it_always_was(avia_map):
    _, queries = avia_map
    for name in ("scan_000005", "scan_000237"):
        assert prepare_cloud(queries[name].history, OUTDOOR, "scans").shake_bins == 0
