"""The source's up direction from IMU readings (REP 145 conventions)."""
import numpy as np
from scipy.spatial.transform import Rotation

from regor_ros.ros.imu_up import ImuUp


def test_orientation_gives_the_reference_z_axis_seen_from_the_imu():
    imu = ImuUp()
    pitched = Rotation.from_euler("y", 20, degrees=True)
    imu.add(10.0, pitched.as_quat(), np.array([0.0, 0.0, 0.0]))   # the accelerations are not used
    up, where = imu.up_at(10.5, 1.0, np.eye(3))
    assert where == "IMU orientation"
    assert np.allclose(up, pitched.inv().apply([0, 0, 1]))
    assert abs(np.degrees(np.arccos(up[2])) - 20.0) < 1e-6


def test_without_orientation_the_mean_acceleration_in_the_window_is_up():
    imu = ImuUp()
    rng = np.random.default_rng(0)
    imu.add(0.0, None, np.array([9.81, 0.0, 0.0]))   # too old: outside the window
    for t in np.linspace(9.1, 10.0, 50):            # a level IMU on a bumpy road
        imu.add(t, None, np.array([0.0, 0.0, 9.81]) + rng.normal(0, 1.0, 3))
    up, where = imu.up_at(10.0, 1.0, np.eye(3))
    assert where.startswith("mean IMU acceleration of 50")
    assert np.degrees(np.arccos(up[2])) < 2.0


def test_the_mounting_turns_the_up_into_the_scan_frame_and_no_reading_gives_none():
    imu = ImuUp()
    assert imu.up_at(5.0, 1.0, np.eye(3))[0] is None
    imu.add(5.0, None, np.array([0.0, 0.0, 9.81]))
    assert imu.up_at(7.0, 1.0, np.eye(3))[0] is None            # the reading is too old for that scan
    R_sensor_imu = Rotation.from_euler("x", 90, degrees=True).as_matrix()   # IMU mounted on its side
    up, _ = imu.up_at(5.2, 1.0, R_sensor_imu)
    assert np.allclose(up, [0.0, -1.0, 0.0])


def test_a_turning_sensor_turns_its_readings_into_the_frame_at_the_scan_by_its_gyro():
    """Pitching at 20 deg/s for the second before the scan: the plain mean of its accelerations is
    gravity smeared over where it pointed (about 10 deg off); turned by the gyro into the frame of
    the last reading, the mean is the up at the scan."""
    rate = np.radians(20.0)
    stamps = np.linspace(9.0, 10.0, 201)
    body = Rotation.from_euler("y", rate * (stamps - 9.0)[:, None])     # the sensor in a level frame
    readings = body.inv().apply([0.0, 0.0, 9.81])
    truth = body[-1].inv().apply([0.0, 0.0, 1.0])
    smeared, with_gyro = ImuUp(), ImuUp()
    for t, a in zip(stamps, readings, strict=True):
        smeared.add(t, None, a)
        with_gyro.add(t, None, a, np.array([0.0, rate, 0.0]))
    off = [np.degrees(np.arccos(np.clip(imu.up_at(10.0, 1.0, np.eye(3))[0] @ truth, -1, 1)))
           for imu in (smeared, with_gyro)]
    assert off[0] > 8.0 and off[1] < 0.1, off
