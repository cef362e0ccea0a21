"""initial_guess messages into search regions."""
import numpy as np
from geometry_msgs.msg import PoseWithCovarianceStamped

from regor_ros.ros.initial_guess import region_of_guess


def guess(x, y, z, covariance):
    msg = PoseWithCovarianceStamped()
    msg.pose.pose.position.x, msg.pose.pose.position.y, msg.pose.pose.position.z = x, y, z
    msg.pose.covariance = [float(v) for v in np.asarray(covariance, dtype=float).reshape(-1)]
    return msg


def test_radius_is_sigmas_times_the_least_certain_direction():
    cov = np.zeros((6, 6))
    cov[0, 0], cov[1, 1], cov[5, 5] = 4.0, 0.25, 0.07   # x 2 m, y 0.5 m, yaw (ignored)
    region = region_of_guess(guess(1.0, 2.0, 0.5, cov), sigmas=3.0, min_radius=0.5, max_radius=50.0)
    np.testing.assert_allclose(region.centre, [1.0, 2.0, 0.5])
    assert region.radius == 6.0


def test_radius_is_bounded_and_a_broken_covariance_means_the_widest():
    rviz = np.zeros((6, 6))                               # what RViz's 2D Pose Estimate sends
    rviz[0, 0] = rviz[1, 1] = 0.25
    assert region_of_guess(guess(0, 0, 0, rviz), 3.0, 2.0, 50.0).radius == 2.0     # at least min
    huge = np.eye(6) * 1e6
    assert region_of_guess(guess(0, 0, 0, huge), 3.0, 2.0, 50.0).radius == 50.0    # at most max
    broken = np.eye(6)
    broken[0, 0] = -1.0
    assert region_of_guess(guess(0, 0, 0, broken), 3.0, 2.0, 50.0).radius == 50.0
    broken[0, 0] = np.nan
    assert region_of_guess(guess(0, 0, 0, broken), 3.0, 2.0, 50.0).radius == 50.0
