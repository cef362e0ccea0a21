"""A relocalization hint restricts the search to where the robot can be."""
import numpy as np
import pytest
from conftest import load_map_query

from regor_ros.core import RegistrationError, RegorConfig, SearchRegion, prepare_cloud, register
from regor_ros.core.metrics import is_success

SHIFT = np.array([300.0, 0.0, 0.0])  # the second copy of the map: far beyond the scan's reach


@pytest.fixture(scope="module")
def twin_map():
    """A real scan and a map made of two copies of its real map 300 m apart: without a hint the
    scan fits both equally; only the hint can say which."""
    scan, cloud, T_gt = load_map_query("fastlio_avia_hku2", "scan_000005")
    config = RegorConfig.preset("outdoor")
    prepared = prepare_cloud(np.vstack([cloud, cloud + SHIFT]), config, viewpoint=None)
    T_copy = T_gt.copy()
    T_copy[:3, 3] += SHIFT
    return scan, prepared, T_gt, T_copy, config


@pytest.mark.parametrize("copy", [False, True])
def test_the_hint_picks_the_copy_it_points_at(twin_map, copy):
    scan, prepared, T_gt, T_copy, config = twin_map
    truth = T_copy if copy else T_gt
    hint = SearchRegion.checked(truth[:3, 3] + [2.0, -1.0, 0.0], 5.0)
    result = register(scan, prepared, config, search_region=hint)
    assert result.accepted, result.reason
    assert is_success(result.transform, truth, "outdoor")
    assert result.num_target_keypoints < 0.6 * len(prepared)  # one copy at most was searched


def test_a_pose_outside_the_hinted_region_is_not_accepted(twin_map):
    scan, prepared, T_gt, _, config = twin_map
    # 30 m off with a 5 m radius: the map around is still searched (the scan reaches farther),
    # the true place is found, but it is not where the hint says: not accepted
    hint = SearchRegion.checked(T_gt[:3, 3] + [30.0, 0.0, 0.0], 5.0)
    result = register(scan, prepared, config, search_region=hint)
    assert not result.accepted
    assert "hinted position" in result.reason


def test_a_hint_where_the_map_is_empty_says_so(twin_map):
    scan, prepared, T_gt, _, config = twin_map
    with pytest.raises(RegistrationError, match="is the hint in the target's frame"):
        register(scan, prepared, config, search_region=SearchRegion.checked(T_gt[:3, 3] + [150.0, 0, 0], 5.0))
    with pytest.raises(RegistrationError, match="radius"):
        SearchRegion.checked((0, 0, 0), -1.0)
