import numpy as np
import pytest
from conftest import DATA, moved_pair, require_shared_data

from regor_ros.bench.datasets import load_sequence
from regor_ros.core import RegistrationError, RegorConfig, for_clouds_seen_from, prepare_cloud, register
from regor_ros.core.features import largest_plane, surface_normals
from regor_ros.core.metrics import is_success


def test_largest_plane_finds_the_ground_and_nothing_else():
    rng = np.random.default_rng(0)
    ground = np.c_[rng.uniform(-10, 10, (5000, 2)), rng.normal(scale=0.01, size=5000)]
    box = rng.uniform([1, 1, 0.5], [3, 4, 3], (800, 3))
    mask = largest_plane(np.r_[ground, box], 0.1)
    assert mask[:5000].all() and not mask[5000:].any()


def test_ground_removal_is_repeatable():
    src, _, _, _ = moved_pair("lidar_koide_251371071_to_251370668", 1)
    cfg, scan = RegorConfig.preset("outdoor"), {"viewpoint": np.zeros(3)}
    first, second = prepare_cloud(src, cfg, **scan), prepare_cloud(src, cfg, **scan)
    assert first.ground_removed and len(first) < len(prepare_cloud(src, cfg.replace({"remove_ground": False}), **scan))
    np.testing.assert_array_equal(first.points, second.points)


def test_the_ground_stays_in_a_cloud_without_viewpoint_and_in_a_scan_registered_against_one():
    src, tgt, _, _ = moved_pair("lidar_koide_251371071_to_251370668", 1)
    cfg = RegorConfig.preset("outdoor").replace({"features.normals_toward_sensors": False})   # one convention
    scan, aggregated = prepare_cloud(src, cfg, viewpoint=np.zeros(3)), prepare_cloud(tgt, cfg)
    assert scan.ground_removed and not aggregated.ground_removed   # a map has no rings to match
    assert len(aggregated) > len(prepare_cloud(tgt, cfg, viewpoint=np.zeros(3)))   # its ground's keypoints
    with pytest.raises(RegistrationError, match="ground removed"):
        register(scan, aggregated, cfg)                # prepared apart under two conventions: refused
    result = register(src, aggregated, cfg)            # a raw scan follows the map
    assert result.num_source_keypoints == len(prepare_cloud(src, cfg.replace({"remove_ground": False}),
                                                            viewpoint=np.zeros(3)))
    paired = for_clouds_seen_from(cfg, np.zeros(3), None)   # one pair prepared cloud by cloud
    assert not prepare_cloud(src, paired, viewpoint=np.zeros(3)).ground_removed


def test_prepared_cloud_has_unit_features_and_normals(kitchen_pair):
    cloud = prepare_cloud(kitchen_pair[0], RegorConfig())
    assert cloud.features.shape == (len(cloud), 33) and cloud.normals.shape == (len(cloud), 3)
    np.testing.assert_allclose(np.linalg.norm(cloud.features, axis=1), 1.0, atol=1e-4)
    np.testing.assert_allclose(np.linalg.norm(cloud.normals, axis=1), 1.0, atol=1e-6)
    assert cloud.input_size == len(kitchen_pair[0])


@pytest.mark.parametrize("pair, preset", [("lidar_koide_251371071_to_251370668", "outdoor"),
                                          ("3dmatch_redkitchen_5_6_ds", "indoor")])
def test_features_are_open3d_fpfh_up_to_bin_edges(pair, preset):
    """The compiled FPFH must stay the FPFH the pipeline was measured with: Open3D's histograms,
    where at most a few neighbours at a bin edge fall in the next bin, or tie at the max_nn-th
    distance and are kept in another's place."""
    import open3d as o3d
    src, _, _, _ = moved_pair(pair, 1)
    cfg = RegorConfig.preset(preset).replace({"remove_ground": False})
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


def test_normals_are_open3d_s_to_the_bit_and_face_the_sensors():
    """Normals are computed on every core, not by Open3D (one core, holding the interpreter lock),
    but they must be the normals everything was measured with, to the bit: Open3D's, with their
    signs turned toward the nearest sensor. Among the fragments is one where two neighbours tied in
    distance change a normal (their order is the one only Open3D's kd-tree knows)."""
    import open3d as o3d
    require_shared_data("the pairs")
    from regor_ros.core.range_image import nearest_viewpoint
    for pair, preset in (("pairs_scenes/3dmatch_studyroom_27_32", "indoor"),
                         ("pairs_scenes/3dmatch_home_at_2_31", "indoor"),
                         ("pairs/lidar_koide_251371071_to_251370668", "outdoor")):
        cfg = RegorConfig.preset(preset).features
        for name in ("src.npy", "tgt.npy"):
            down = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.load(DATA / pair / name)[:, :3]))
            down = down.voxel_down_sample(cfg.voxel_size)
            points = np.asarray(down.points).copy()
            sensors = points.mean(axis=0, keepdims=True) + [0.0, 0.0, 1.5]
            ours, turned = (surface_normals(points, cfg.normal_radius, cfg.normal_max_nn, s) for s in (None, sensors))
            down.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=cfg.normal_radius,
                                                                       max_nn=cfg.normal_max_nn))
            theirs = np.asarray(down.normals)
            np.testing.assert_array_equal(ours, theirs)
            away = ((nearest_viewpoint(sensors, points) - points) * theirs).sum(axis=1) < 0
            np.testing.assert_array_equal(turned, np.where(away[:, None], -theirs, theirs))


def test_normals_on_a_lattice_are_open3d_s_and_a_floor_faces_both_sensors(monkeypatch):
    """On a lattice distances tie everywhere, several pairs in a neighbourhood, some only in the
    last bit: Open3D's pass over the whole cloud, or its kd-tree asked point by point, gives the
    same normals as Open3D. A floor seen from above on one side and from below on the other faces
    both ways."""
    import open3d as o3d

    from regor_ros.core import features
    lattice = np.mgrid[0:30, 0:30, 0:3].reshape(3, -1).T * 0.05 + 0.0123
    down = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(lattice))
    down.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.1, max_nn=30))
    for share in (features.TIED_SHARE_FOR_OPEN3D, 1.0):
        monkeypatch.setattr(features, "TIED_SHARE_FOR_OPEN3D", share)
        np.testing.assert_array_equal(surface_normals(lattice, 0.1, 30), np.asarray(down.normals))
    rng = np.random.default_rng(3)
    floor = np.c_[rng.uniform(-5, 5, (2000, 2)), np.zeros(2000)]
    faced = surface_normals(floor, 0.5, 30, np.array([[-3.0, 0.0, 2.0], [3.0, 0.0, -2.0]]))
    left = floor[:, 0] < 0
    np.testing.assert_allclose(np.abs(faced[:, 2]), 1.0)
    assert (faced[left, 2] > 0).all() and (faced[~left, 2] < 0).all()


def test_a_revisit_seen_from_the_other_way_is_found_once_normals_face_the_sensors():
    """Revisit scan 191 looks the other way from the map's nearest pose. With the solver's signs
    (decided in each cloud's own axes) its FPFH find almost none of their true matches in the map
    and the search settles elsewhere; with every normal facing the sensor that saw it, the place
    is found and published. (With the solver's signs the outdoor preset's verification picks may
    also reach it, from the search's next places: off here, to compare the features alone.)"""
    require_shared_data("the revisit sequence")
    cloud, trajectory, queries = load_sequence(DATA / "revisit" / "avia_hku2_loop")
    query = next(q for q in queries if q.id == "scan_000191")
    outcome = {}
    for toward in (True, False):
        cfg = RegorConfig.preset("outdoor").replace({"features.normals_toward_sensors": toward,
                                                     "estimation.visible_candidates": 0})
        prepared = prepare_cloud(cloud, cfg, "map", trajectory=trajectory)
        assert prepared.normals_toward_sensors == toward
        result = register(query.scan, prepared, cfg)
        outcome[toward] = (is_success(result.transform, query.truth, "outdoor"), result.accepted)
    assert outcome == {True: (True, True), False: (False, False)}


def test_both_clouds_compare_under_one_normal_convention(kitchen_pair):
    """Normals face the sensors only when both clouds know theirs; a raw cloud follows a prepared
    one, and two prepared under different conventions, or a raw cloud with no sensor against one
    whose normals face its own, are refused with what to do."""
    src, tgt, _, _ = kitchen_pair
    cfg = RegorConfig().replace({"features.normals_toward_sensors": True})
    scan = prepare_cloud(src, cfg, viewpoint=(0, 0, 0))
    fragment_without_sensor = prepare_cloud(tgt, cfg, viewpoint=None)
    assert scan.normals_toward_sensors and not fragment_without_sensor.normals_toward_sensors
    with pytest.raises(RegistrationError, match="different conventions"):
        register(scan, fragment_without_sensor, cfg)
    with pytest.raises(RegistrationError, match="source_viewpoint"):
        register(src, prepare_cloud(tgt, cfg, viewpoint=(0, 0, 0)), cfg, source_viewpoint=None)
    # the raw scan follows the target: its normals keep the solver's signs, as the target's do
    assert register(src, fragment_without_sensor, cfg, source_viewpoint=(0, 0, 0)).transform.shape == (4, 4)
    assert prepare_cloud(src, RegorConfig(), viewpoint=(0, 0, 0)).normals_toward_sensors   # on by default
    assert not prepare_cloud(src, RegorConfig.preset("object"), viewpoint=(0, 0, 0)).normals_toward_sensors
    # preparing one registration's clouds apart: facing the sensors only if every viewpoint is known
    assert for_clouds_seen_from(cfg, (0, 0, 0), (1, 0, 0)).features.normals_toward_sensors
    assert not for_clouds_seen_from(cfg, (0, 0, 0), None).features.normals_toward_sensors


def test_fpfh_is_the_same_on_one_thread_and_zero_for_a_point_alone():
    """Each point's histogram is summed in its own fixed order, so the thread count changes no
    bit; a point with no neighbour within the radius has no histogram (Open3D's zeros)."""
    import numba

    from regor_ros.core.features import fpfh
    src, _, _, _ = moved_pair("3dmatch_redkitchen_5_6_ds", 1)
    cloud = prepare_cloud(src, RegorConfig.preset("indoor"))
    cfg = RegorConfig.preset("indoor").features
    points = np.vstack([cloud.points, cloud.points.max(axis=0) + 10.0])   # one point far from the rest
    normals = np.vstack([cloud.normals, [0.0, 0.0, 1.0]])
    both = fpfh(points, normals, cfg.fpfh_radius, cfg.fpfh_max_nn)
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        one = fpfh(points, normals, cfg.fpfh_radius, cfg.fpfh_max_nn)
    finally:
        numba.set_num_threads(threads)
    np.testing.assert_array_equal(one, both)
    assert not both[-1].any() and both[:-1].any(axis=1).mean() > 0.99


def _reference_fpfh(points, normals, radius, max_nn):
    """FPFH by its definition, one pair at a time with the arctangent: each point's max_nn - 1
    nearest within the radius, ties to the lower index; SPFH thirds summing to 100; FPFH the
    neighbours' SPFH weighted by one over the squared distance, each third normalised to 100,
    plus the point's own."""
    def bins(p, q):
        d = points[q] - points[p]
        length = np.linalg.norm(d)
        cos1, cos2 = normals[p] @ d / length, normals[q] @ d / length
        u, w, phi = normals[p], normals[q], cos1
        if abs(cos1) < abs(cos2):
            u, w, phi, d = normals[q], normals[p], -cos2, -d
        v = np.cross(d, u)
        v /= np.linalg.norm(v)
        theta = np.arctan2(np.cross(u, v) @ w, u @ w)
        return [min(max(int(np.floor(11 * x)), 0), 10)
                for x in ((theta + np.pi) / (2 * np.pi), (v @ w + 1) / 2, (phi + 1) / 2)]

    n = len(points)
    d2 = ((points[:, None] - points[None]) ** 2).sum(axis=2)
    neighbours = []
    for p in range(n):
        within = [q for q in np.lexsort((np.arange(n), d2[p])) if q != p and d2[p, q] <= radius ** 2]
        neighbours.append(within[:max_nn - 1])
    spfh = np.zeros((n, 33))
    for p in range(n):
        for q in neighbours[p]:
            for third, b in enumerate(bins(p, q)):
                spfh[p, 11 * third + b] += 100.0 / len(neighbours[p])
    out = np.zeros((n, 33))
    for p in range(n):
        for q in neighbours[p]:
            out[p] += spfh[q] / d2[p, q]
        for third in range(3):
            part = out[p, 11 * third:11 * third + 11]
            part *= 100.0 / part.sum()
        out[p] += spfh[p]
    return out


def test_fpfh_is_its_definition_where_neighbours_tie_at_the_cut_off():
    """On a lattice whole shells of neighbours lie at one distance, so the max_nn-th nearest
    ties with others; the kernel keeps the lower indices, bins every pair as the arctangent
    does (it counts bin edges instead), and sums the histograms as the definition does."""
    from regor_ros.core.features import fpfh
    spacing = 1 / 16   # exact in binary: the lattice's distances tie to the last bit
    grid = np.stack(np.meshgrid(np.arange(7), np.arange(6), np.arange(2), indexing="ij"), -1).reshape(-1, 3)
    points = grid * spacing
    rng = np.random.default_rng(3)
    normals = rng.normal(size=points.shape) + [0.0, 0.0, 3.0]
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    for radius, max_nn in ((2.5 * spacing, 12), (1.5 * spacing, 30), (3.2 * spacing, 40)):
        expected = _reference_fpfh(points, normals, radius, max_nn)
        np.testing.assert_allclose(fpfh(points, normals, radius, max_nn), expected, rtol=1e-5, atol=1e-4)
