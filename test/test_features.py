import numpy as np
from conftest import moved_pair

from regor_ros.core import RegorConfig, prepare_cloud
from regor_ros.core.features import largest_plane


def test_largest_plane_finds_the_ground_and_nothing_else():
    rng = np.random.default_rng(0)
    ground = np.c_[rng.uniform(-10, 10, (5000, 2)), rng.normal(scale=0.01, size=5000)]
    box = rng.uniform([1, 1, 0.5], [3, 4, 3], (800, 3))
    mask = largest_plane(np.r_[ground, box], 0.1)
    assert mask[:5000].all() and not mask[5000:].any()


def test_ground_removal_is_repeatable():
    src, _, _, _ = moved_pair("lidar_koide_251371071_to_251370668", 1)
    cfg = RegorConfig.preset("outdoor")
    first, second = prepare_cloud(src, cfg), prepare_cloud(src, cfg)
    assert len(first) < len(prepare_cloud(src, cfg.replace({"remove_ground": False})))
    np.testing.assert_array_equal(first.points, second.points)


def test_prepared_cloud_has_unit_features_and_normals(kitchen_pair):
    cloud = prepare_cloud(kitchen_pair[0], RegorConfig())
    assert cloud.features.shape == (len(cloud), 33) and cloud.normals.shape == (len(cloud), 3)
    np.testing.assert_allclose(np.linalg.norm(cloud.features, axis=1), 1.0, atol=1e-4)
    np.testing.assert_allclose(np.linalg.norm(cloud.normals, axis=1), 1.0, atol=1e-6)
    assert cloud.input_size == len(kitchen_pair[0])


def test_features_are_open3d_fpfh_up_to_bin_edges():
    """The tensor FPFH (all cores) must stay the FPFH the pipeline was measured with: the legacy
    histograms, where at most a few neighbours at a bin edge fall in the next bin."""
    import open3d as o3d
    src, _, _, _ = moved_pair("lidar_koide_251371071_to_251370668", 1)
    cfg = RegorConfig.preset("outdoor").replace({"remove_ground": False})
    cloud = prepare_cloud(src, cfg)
    down = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud.points))
    down.normals = o3d.utility.Vector3dVector(cloud.normals)
    legacy = np.asarray(o3d.pipelines.registration.compute_fpfh_feature(down, o3d.geometry.KDTreeSearchParamHybrid(
        radius=cfg.features.fpfh_radius, max_nn=cfg.features.fpfh_max_nn)).data, dtype=np.float32).T
    legacy /= np.linalg.norm(legacy, axis=1, keepdims=True) + 1e-6
    differs = np.abs(cloud.features - legacy).max(axis=1) > 1e-5
    assert differs.mean() < 0.01
    np.testing.assert_allclose(cloud.features[~differs], legacy[~differs], atol=1e-5)


def test_fpfh_in_slabs_is_the_fpfh_of_the_whole_cloud():
    """A map's FPFH is computed in slabs to bound memory; each slab carries the points within two
    radii, so every keypoint gets the histogram it gets in one call."""
    from regor_ros.core.features import fpfh
    src, _, _, _ = moved_pair("lidar_koide_251371071_to_251370668", 1)
    cfg = RegorConfig.preset("outdoor").features
    cloud = prepare_cloud(src, RegorConfig.preset("outdoor"))
    whole = fpfh(cloud.points, cloud.normals, cfg.fpfh_radius, cfg.fpfh_max_nn, chunk=len(cloud))
    slabs = fpfh(cloud.points, cloud.normals, cfg.fpfh_radius, cfg.fpfh_max_nn, chunk=len(cloud) // 7)
    np.testing.assert_array_equal(slabs, whole)
