import numpy as np
import open3d as o3d

from regor_ros.core import RegorConfig, prepare_cloud
from regor_ros.core.features import remove_largest_plane


def test_largest_plane_is_removed_and_the_rest_kept():
    rng = np.random.default_rng(0)
    ground = np.c_[rng.uniform(-10, 10, (5000, 2)), rng.normal(scale=0.01, size=5000)]
    box = rng.uniform([1, 1, 0.5], [3, 4, 3], (800, 3))
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.r_[ground, box]))
    kept = np.asarray(remove_largest_plane(pcd, 0.1).points)
    assert len(kept) == 800
    assert kept[:, 2].min() > 0.4


def test_prepared_cloud_has_unit_features_and_normals(kitchen_pair):
    cloud = prepare_cloud(kitchen_pair[0], RegorConfig())
    assert cloud.features.shape == (len(cloud), 33) and cloud.normals.shape == (len(cloud), 3)
    np.testing.assert_allclose(np.linalg.norm(cloud.features, axis=1), 1.0, atol=1e-4)
    np.testing.assert_allclose(np.linalg.norm(cloud.normals, axis=1), 1.0, atol=1e-6)
    assert cloud.input_size == len(kitchen_pair[0])
