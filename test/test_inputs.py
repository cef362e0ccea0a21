"""What the node's worker does next (ros/inputs.py, no ROS needed): stale inputs, map first, on demand."""
from types import SimpleNamespace

import numpy as np

from regor_ros.ros.inputs import InputBuffer, PrepareMap, Register


def settings(**changes):
    values = dict(mode="pairs", registration="continuous", max_stamp_difference=0.0, map_file="",
                  map_trajectory_file="")
    values.update(changes)
    return SimpleNamespace(viewpoints=lambda: ((0, 0, 0), None), **values)


POINTS = np.zeros((10, 3))
DECISECOND = 10**8   # [ns]: stamps are exact integers


def test_pairs_register_the_newest_of_each_and_count_what_they_replaced():
    inputs = InputBuffer()
    assert not inputs.store("source", "camera", 10 * DECISECOND, POINTS, "pairs")
    assert inputs.next_job(settings(), None, None, False) is None          # no target yet
    assert inputs.store("source", "camera", 20 * DECISECOND, POINTS, "pairs")   # the first was never registered
    inputs.store("target", "map", 21 * DECISECOND, POINTS, "pairs")
    job = inputs.next_job(settings(), None, None, False)
    assert isinstance(job, Register) and job.source.stamp == 2.0 and job.target.stamp == 2.1
    inputs.taken(job)
    assert inputs.next_job(settings(), None, None, False) is None          # nothing new
    inputs.store("source", "camera", 90 * DECISECOND, POINTS, "pairs")
    assert inputs.next_job(settings(max_stamp_difference=1.0), None, None, False) is None   # stamps too far apart


def test_map_mode_prepares_the_map_first_and_on_demand_waits_for_a_call():
    inputs = InputBuffer()
    inputs.store("source", "camera", 10 * DECISECOND, POINTS, "map")
    inputs.store("target", "map", 5 * DECISECOND, POINTS, "map")
    first = inputs.next_job(settings(mode="map"), "features", None, False)
    assert isinstance(first, PrepareMap) and first.target.stamp == 0.5
    assert not inputs.store("target", "map", 7 * DECISECOND, POINTS, "map")   # a newer map is not a stale input
    key = inputs.map_key(settings(mode="map"), "features")
    job = inputs.next_job(settings(mode="map"), "features", key, True)
    assert isinstance(job, Register) and job.target is None                # against the prepared map
    assert inputs.next_job(settings(mode="map", registration="on_demand"), "features", key, True) is None
    inputs.relocalize_after = inputs.serials["source"]
    assert inputs.next_job(settings(mode="map", registration="on_demand"), "features", key, True) is None
    inputs.store("source", "camera", 20 * DECISECOND, POINTS, "map")                       # the scan after the call
    assert isinstance(inputs.next_job(settings(mode="map", registration="on_demand"), "features", key, True),
                      Register)
    from_file = inputs.next_job(settings(mode="map", map_file="/maps/a.pcd"), "features", key, True)
    assert isinstance(from_file, PrepareMap) and from_file.target is None and from_file.key.file == "/maps/a.pcd"
