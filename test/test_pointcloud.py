"""PointCloud2 <-> numpy on the real message classes, for every layout the node accepts."""
import numpy as np
import pytest
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header

from regor_ros.ros.pointcloud import CloudError, cloud_to_xyz, xyz_to_cloud

F32, F64 = PointField.FLOAT32, PointField.FLOAT64


def make_cloud(xyz, datatype=F32, big_endian=False, padding=0, height=1, extra_field=True,
               row_padding=0):
    """A cloud with x, y, z of ``datatype`` at shuffled offsets inside a padded point."""
    size = 4 if datatype == F32 else 8
    step = 3 * size + 4 + padding
    offsets = {"intensity": 0, "z": 4, "x": 4 + size, "y": 4 + 2 * size}
    n = len(xyz)
    width = n // height
    order = ">" if big_endian else "<"
    layout = np.dtype({"names": ["intensity", "x", "y", "z"],
                       "formats": [order + "f4"] + [order + ("f4" if size == 4 else "f8")] * 3,
                       "offsets": [offsets[k] for k in ["intensity", "x", "y", "z"]],
                       "itemsize": step})
    points = np.zeros(n, dtype=layout)
    points["x"], points["y"], points["z"] = xyz.T
    points["intensity"] = 7.0
    rows = points.tobytes()
    row_bytes = width * step
    data = b"".join(rows[r * row_bytes:(r + 1) * row_bytes] + b"\xab" * row_padding
                    for r in range(height))
    msg = PointCloud2(header=Header(frame_id="lidar"), height=height, width=width,
                      is_bigendian=big_endian, point_step=step, row_step=row_bytes + row_padding,
                      data=data, is_dense=False)
    fields = [PointField(name=k, offset=offsets[k], datatype=datatype, count=1) for k in "xyz"]
    if extra_field:
        fields.append(PointField(name="intensity", offset=0, datatype=F32, count=1))
    msg.fields = fields
    return msg


@pytest.fixture
def xyz():
    return np.random.default_rng(0).normal(size=(60, 3)) * 10


@pytest.mark.parametrize("datatype", [F32, F64])
@pytest.mark.parametrize("big_endian", [False, True])
def test_round_trip_of_padded_layouts(xyz, datatype, big_endian):
    msg = make_cloud(xyz, datatype, big_endian, padding=5)
    tol = 1e-5 if datatype == F32 else 0
    np.testing.assert_allclose(cloud_to_xyz(msg), xyz, rtol=tol, atol=tol)


def test_organised_cloud_with_row_padding(xyz):
    msg = make_cloud(xyz, F64, height=6, row_padding=9)
    assert (msg.height, msg.width) == (6, 10)
    np.testing.assert_array_equal(cloud_to_xyz(msg), xyz)


def test_nan_and_inf_points_are_dropped(xyz):
    xyz[3] = np.nan
    xyz[5, 1] = np.inf
    out = cloud_to_xyz(make_cloud(xyz, F64))
    assert len(out) == 58
    np.testing.assert_array_equal(out, np.delete(xyz, [3, 5], axis=0))


def test_xyz_to_cloud_round_trip(xyz):
    msg = xyz_to_cloud(xyz, Header(frame_id="map"))
    assert msg.point_step == 12 and msg.width == 60 and msg.header.frame_id == "map"
    np.testing.assert_allclose(cloud_to_xyz(msg), xyz, rtol=1e-6)


def bad(msg, **changes):
    for k, v in changes.items():
        setattr(msg, k, v)
    return msg


@pytest.mark.parametrize("mutate, message", [
    (lambda m: bad(m, fields=[f for f in m.fields if f.name != "z"]), "no z field"),
    (lambda m: bad(m, width=0), "empty cloud"),
    (lambda m: bad(m, data=bytes(m.data)[:100]), "data holds 100 bytes"),
    (lambda m: bad(m, point_step=8), "does not fit in point_step 8"),
    (lambda m: bad(m, row_step=10), "row_step 10 is smaller"),
    (lambda m: bad(m, fields=[PointField(name=a, offset=0, datatype=PointField.UINT16, count=1)
                              for a in "xyz"]), "only FLOAT32"),
    (lambda m: bad(m, data=np.full(len(m.data), 255, np.uint8).tobytes()), "NaN"),
])
def test_malformed_clouds_raise_a_clear_error(xyz, mutate, message):
    with pytest.raises(CloudError, match=message):
        cloud_to_xyz(mutate(make_cloud(xyz)))
