"""A LiDAR-driver-like publisher in its own process, for transport tests: a real cloud as
x y z intensity ring time (32 bytes a point) on source_cloud, one message per line read from
stdin (the line is the stamp in seconds), with the reliability given on the command line. It
sets no Fast DDS profile of its own: it runs with whatever environment the test gives it."""
import sys
import time

import numpy as np
import rclpy
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header

FIELDS = [("x", 0, PointField.FLOAT32), ("y", 4, PointField.FLOAT32), ("z", 8, PointField.FLOAT32),
          ("intensity", 12, PointField.FLOAT32), ("ring", 16, PointField.UINT16), ("time", 20, PointField.FLOAT32)]
POINT_STEP = 32
MATCH_TIMEOUT_S = 30.0


def driver_cloud(points: np.ndarray, stamp: int, frame: str) -> PointCloud2:
    n = len(points)
    data = np.zeros((n, POINT_STEP), dtype=np.uint8)
    data[:, :12] = points.astype(np.float32).view(np.uint8).reshape(n, 12)
    data[:, 12:16] = np.linspace(0, 255, n, dtype=np.float32).view(np.uint8).reshape(n, 4)
    data[:, 16:18] = (np.arange(n) % 128).astype(np.uint16).view(np.uint8).reshape(n, 2)
    data[:, 20:24] = np.linspace(0, 0.1, n, dtype=np.float32).view(np.uint8).reshape(n, 4)
    return PointCloud2(header=Header(frame_id=frame, stamp=rclpy.time.Time(seconds=stamp).to_msg()),
                       height=1, width=n, point_step=POINT_STEP, row_step=POINT_STEP * n, is_dense=True,
                       fields=[PointField(name=a, offset=o, datatype=t, count=1) for a, o, t in FIELDS],
                       data=data.tobytes())


def wait_for_subscriber(publisher) -> None:
    """A volatile writer delivers only to readers it has already matched: a message published
    before the match is lost for good, so wait for one (as a real driver's next scan would)."""
    deadline = time.monotonic() + MATCH_TIMEOUT_S
    while publisher.get_subscription_count() == 0 and time.monotonic() < deadline:
        time.sleep(0.05)


def main(cloud_file: str, reliability: str) -> None:
    points = np.load(cloud_file)
    rclpy.init()
    node = rclpy.create_node("driver_like_publisher")
    qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5,
                     reliability=ReliabilityPolicy.RELIABLE if reliability == "reliable"
                     else ReliabilityPolicy.BEST_EFFORT)
    publisher = node.create_publisher(PointCloud2, "source_cloud", qos)
    print("ready", flush=True)
    for line in sys.stdin:
        wait_for_subscriber(publisher)
        publisher.publish(driver_cloud(points, int(line), "velodyne"))
        print("published", line.strip(), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
