"""sensor_msgs/PointCloud2 <-> (N, 3) numpy arrays, through a zero-copy structured view."""
from __future__ import annotations

import numpy as np
from sensor_msgs.msg import PointCloud2, PointField

from ..core import RegistrationError

_FLOAT_TYPES = {PointField.FLOAT32: "f4", PointField.FLOAT64: "f8"}
_TYPE_SIZES = {PointField.INT8: 1, PointField.UINT8: 1, PointField.INT16: 2, PointField.UINT16: 2,
               PointField.INT32: 4, PointField.UINT32: 4, PointField.FLOAT32: 4,
               PointField.FLOAT64: 8}


class CloudError(RegistrationError):
    """A PointCloud2 message that cannot be read; the message says what is wrong with it."""


def cloud_to_xyz(msg: PointCloud2) -> np.ndarray:
    """x, y, z of every finite point as float64 (N, 3).

    Accepts any layout with float32 or float64 x, y, z fields (any offsets and point_step,
    organised or not, row padding, either endianness). Raises CloudError for malformed messages.
    """
    fields = {f.name: f for f in msg.fields}
    missing = [axis for axis in "xyz" if axis not in fields]
    if missing:
        raise CloudError(f"no {', '.join(missing)} field (fields: {', '.join(fields) or 'none'})")
    width, height, step = int(msg.width), int(msg.height), int(msg.point_step)
    if width == 0 or height == 0:
        raise CloudError(f"empty cloud (width {width}, height {height})")
    order = ">" if msg.is_bigendian else "<"
    formats = []
    for axis in "xyz":
        f = fields[axis]
        if f.datatype not in _FLOAT_TYPES:
            raise CloudError(f"field {axis} has datatype {f.datatype}; only FLOAT32 (7) and "
                             "FLOAT64 (8) coordinates are supported")
        if f.offset + _TYPE_SIZES[f.datatype] > step:
            raise CloudError(f"field {axis} (offset {f.offset}) does not fit in point_step {step}")
        formats.append(order + _FLOAT_TYPES[f.datatype])
    row_step = int(msg.row_step) or width * step
    if row_step < width * step:
        raise CloudError(f"row_step {row_step} is smaller than width {width} x point_step {step}")
    data = np.frombuffer(msg.data, dtype=np.uint8)
    if len(data) < row_step * (height - 1) + width * step:
        raise CloudError(f"data holds {len(data)} bytes, the header promises {row_step * height} "
                         f"({height} rows of {row_step})")
    layout = np.dtype({"names": list("xyz"), "formats": formats,
                       "offsets": [fields[a].offset for a in "xyz"], "itemsize": step})
    rows = np.lib.stride_tricks.as_strided(data, shape=(height, width * step),
                                           strides=(row_step, 1))
    points = np.ascontiguousarray(rows).view(layout).reshape(-1)
    xyz = np.stack([points["x"], points["y"], points["z"]], axis=1).astype(np.float64)
    finite = np.isfinite(xyz).all(axis=1)
    if not finite.any():
        raise CloudError(f"all {len(xyz)} points are NaN or infinite")
    return xyz[finite]


def xyz_to_cloud(xyz: np.ndarray, header) -> PointCloud2:
    """An unorganised float32 x, y, z cloud."""
    points = np.ascontiguousarray(xyz, dtype="<f4")
    msg = PointCloud2()
    msg.header = header
    msg.height, msg.width = 1, len(points)
    msg.fields = [PointField(name=a, offset=4 * i, datatype=PointField.FLOAT32, count=1)
                  for i, a in enumerate("xyz")]
    msg.is_bigendian = False
    msg.point_step, msg.row_step = 12, 12 * len(points)
    msg.is_dense = True
    msg.data = points.tobytes()
    return msg
