"""The whole core on real pairs, each source moved by a random rigid motion."""
import numpy as np
import pytest
from conftest import DATA, EARLIER_INDOOR, load_pair, load_threedmatch, moved_pair, require_shared_data

from regor_ros.core import RegistrationError, RegorConfig, prepare_cloud, register
from regor_ros.core.gate.judge import passes
from regor_ros.core.geometry import transform_points
from regor_ros.core.initial import same_place
from regor_ros.core.metrics import is_success, random_rigid_motion, rotation_error_deg, translation_error
from regor_ros.core.pipeline import _register_once, _undo_turn, regrid_rotation

# (pair, overlap high enough that the quality gate must accept the correct pose)
REAL_PAIRS = [("3dmatch_redkitchen_0_5_ds", True), ("3dmatch_redkitchen_6_21_ds", False),
              ("3dmatch_hotel_umd_8_15_ds", True), ("lidar_koide_251371071_to_251370668", True),
              ("kitti07_submap_2_3", True), ("stanford_bunny_045_to_000", True)]


@pytest.mark.parametrize("name, must_accept", REAL_PAIRS)
def test_registers_real_pairs_from_an_arbitrary_pose(name, must_accept):
    src, tgt, T_gt, kind = moved_pair(name, seed=11)
    result = register(src, tgt, RegorConfig.preset(kind))
    assert is_success(result.transform, T_gt, kind), (
        f"RE {rotation_error_deg(result.transform, T_gt):.1f} deg, "
        f"TE {translation_error(result.transform, T_gt):.2f} m")
    if must_accept:
        assert result.accepted, result.reason
    # regeneration ends with many more correct pairs than the initial matches hold (outdoors, with
    # the normals facing the sensors, the initial matches hold a third of the keypoints already)
    assert result.num_inliers > 2 * result.initial.inlier.sum()


def test_result_contents(kitchen_pair):
    src, tgt, T_gt, _ = kitchen_pair
    r = register(src, tgt, RegorConfig())
    assert r.transform.shape == (4, 4) and np.allclose(r.transform[3], [0, 0, 0, 1])
    assert np.allclose(r.transform[:3, :3] @ r.transform[:3, :3].T, np.eye(3), atol=1e-9)
    assert len(r.initial.source) == r.num_source_keypoints == len(r.initial.inlier)
    assert len(r.final.source) == r.num_inliers
    assert 0 < r.fitness <= 1 and r.inlier_rmse < 0.1
    assert r.covariance.shape == (6, 6)
    assert set(r.timings) >= {"features", "matching", "initial", "regeneration", "estimation", "total"}
    assert r.stage_sizes["initial_inliers"] > 0 and "stage2" in r.stage_sizes


def test_same_seed_same_pose_and_prepared_target_reused(kitchen_pair):
    src, tgt, _, _ = kitchen_pair
    cfg = RegorConfig()
    target = prepare_cloud(tgt, cfg, "target")
    first = register(src, target, cfg)
    second = register(src, target, cfg)
    np.testing.assert_array_equal(first.transform, second.transform)
    assert second.timings["features"] < first.timings["total"]


def test_a_retry_result_is_given_in_the_source_frame(kitchen_pair):
    src, tgt, T_gt, _ = kitchen_pair
    cfg = RegorConfig()
    turn = regrid_rotation(cfg.seed, 1)
    assert rotation_error_deg(turn, np.eye(4)) > 30.0   # a real turn, so a frame slip would show
    target = prepare_cloud(tgt, cfg, "target")
    turned = prepare_cloud(transform_points(turn, src), cfg, "source")
    r = _undo_turn(_register_once(turned, target, cfg, None), turn)
    assert is_success(r.transform, T_gt, "indoor")
    keypoints = prepare_cloud(src, cfg, "source").tree
    for pairs in (r.initial, r.final):   # source keypoints lie on the source as given
        assert np.median(keypoints.query(pairs.source)[0]) < cfg.features.voxel_size
    moved = transform_points(r.transform, r.final.source)
    assert np.median(np.linalg.norm(moved - r.final.target, axis=1)) < 0.05


def test_a_rejected_pose_is_retried_and_the_first_attempt_reported(kitchen_pair):
    src, tgt, _, _ = kitchen_pair
    strict = RegorConfig().replace({"min_inliers": 10 ** 6})   # no pose can pass
    once = register(src, tgt, strict)
    thrice = register(src, tgt, strict.replace({"retries": 2}))
    assert (once.attempts, thrice.attempts) == (1, 3) and not thrice.accepted
    np.testing.assert_array_equal(once.transform, thrice.transform)
    assert thrice.reason == once.reason and thrice.summary().attempts == 3
    prepared = prepare_cloud(src, strict, "source")   # cannot be re-gridded
    assert register(prepared, tgt, strict.replace({"retries": 2})).attempts == 1


def test_a_retry_does_not_publish_again_the_place_the_first_attempt_withheld():
    # 3DLoMatch studyroom 65-24: the first attempt slides 1 m along the shelves and is withheld
    # (too few agreeing matches); on a re-drawn grid that same place passes, so re-judging it
    # would publish the slide
    src, tgt, T_gt = load_threedmatch("studyroom", 65, 24)
    cfg = RegorConfig.preset("indoor").replace({"seed": 0})
    first = register(src, tgt, cfg)
    assert not first.accepted and translation_error(first.transform, T_gt) > 0.6
    turn = regrid_rotation(cfg.seed, 1)   # the first retry's grid, as register() draws it
    target = prepare_cloud(tgt, cfg, "target", viewpoint=np.zeros(3))
    turned = prepare_cloud(transform_points(turn, src), cfg, "source", viewpoint=np.zeros(3))
    regridded = _undo_turn(_register_once(turned, target, cfg, None), turn)
    # an attempt is measured, not judged: it would pass the gate
    assert passes(regridded.figures, cfg.acceptance)
    assert same_place(regridded.transform, first.transform, cfg.initial.inlier_threshold)
    retried = register(src, tgt, cfg.replace({"retries": 3}))
    assert not retried.accepted and retried.attempts == 4 and retried.reason == first.reason
    np.testing.assert_array_equal(retried.transform, first.transform)


def test_a_retry_grid_with_too_few_points_ends_the_retries_quietly():
    cube = np.random.default_rng(0).uniform(0.0, 0.3, (300, 3))
    keypoints = len(prepare_cloud(cube, RegorConfig(), "cube"))
    cfg = RegorConfig().replace({"min_points": keypoints, "min_inliers": 10 ** 6, "retries": 2})
    assert len(prepare_cloud(transform_points(regrid_rotation(cfg.seed, 1), cube), RegorConfig(),
                             "turned")) < keypoints   # so the first retry's grid is refused
    r = register(cube, cube, cfg)
    assert not r.accepted and r.attempts == 1


def test_an_accepted_pose_is_not_retried(kitchen_pair):
    src, tgt, _, _ = kitchen_pair
    r = register(src, tgt, RegorConfig().replace({"retries": 3}))
    assert r.accepted and r.attempts == 1


def test_prepared_cloud_with_other_settings_is_refused(kitchen_pair):
    src, tgt, _, _ = kitchen_pair
    target = prepare_cloud(tgt, RegorConfig(), "target")
    with pytest.raises(RegistrationError, match="prepared with other feature settings"):
        register(src, target, RegorConfig().replace({"voxel_size": 0.06}))


@pytest.mark.parametrize("bad, message", [
    (np.zeros((0, 3)), "empty"),
    (np.full((100, 3), np.nan), "NaN"),
    (np.zeros((100, 2)), r"\(N, 3\)"),
    (np.full((100, 3), 1e30), "beyond"),
    ("not a cloud", "numeric"),
    (np.zeros((500, 3)), "after downsampling"),
])
def test_unusable_inputs_raise_one_clear_error(kitchen_pair, bad, message):
    with pytest.raises(RegistrationError, match=message):
        register(bad, kitchen_pair[1], RegorConfig())


MISMATCHED = [("3dmatch_redkitchen_0_5_ds", "3dmatch_home_at_38_41_ds"),
              ("3dmatch_home_at_38_41_ds", "3dmatch_hotel_umd_8_15_ds"),
              ("3dmatch_hotel_umd_8_15_ds", "3dmatch_redkitchen_5_6_ds"),
              ("3dmatch_redkitchen_6_34_ds", "3dmatch_hotel_umd_8_15_ds"),
              ("lidar_koide_251371071_to_251370668", "kitti07_submap_0_1")]


@pytest.mark.parametrize("source_pair, target_pair", MISMATCHED)
def test_scans_of_different_places_are_not_accepted(source_pair, target_pair):
    src, _, _, kind = moved_pair(source_pair, 3)
    tgt = load_pair(target_pair)[1]
    result = register(src, tgt, RegorConfig.preset(kind))
    assert not result.accepted and result.reason


def hotel_scan_moved_by_benchmark_motion_3():
    """A hotel scan, moved as the benchmark's motion 3 moves it, and where its sensor went."""
    hotel = load_pair("3dmatch_hotel_umd_8_15_ds")[0]
    motion = random_rigid_motion([3, 10])   # the benchmark's motion 3 of this pair
    return hotel @ motion[:3, :3].T + motion[:3, 3], motion[:3, 3]


def test_a_real_room_of_another_place_is_rejected_by_the_free_space_check_alone():
    """This hotel scan aligns with a kitchen's walls and floor, with 97 agreeing feature matches;
    only the free-space check tells that the kitchen's surfaces stand inside the hotel room."""
    hotel, sensor = hotel_scan_moved_by_benchmark_motion_3()
    kitchen = load_pair("3dmatch_redkitchen_0_5_ds")[1]
    cfg = RegorConfig().replace({**EARLIER_INDOOR, "seed": 3})
    blind = register(hotel, kitchen, cfg.replace({"max_free_space_violation": 1.0}), source_viewpoint=sensor)
    assert blind.accepted  # every other check passes
    checked = register(hotel, kitchen, cfg, source_viewpoint=sensor)
    assert np.allclose(checked.transform, blind.transform)
    assert not checked.accepted and "max_free_space_violation" in checked.reason
    assert checked.figures.worst_free_space > cfg.acceptance.max_free_space_violation


def test_a_home_fragment_is_not_published_on_a_hotel_fragment():
    """Once a known failure (#13): a home fragment registered onto a hotel fragment (moved as the
    benchmark's motion 4 moves it) aligned with 66 agreeing feature matches, a free-space figure of
    0.02, nothing seen from opposite sides and no rival, and the registration the other way round
    came back to it. With the normals facing the sensors and the gate fitted for them (2026-11-28)
    it is not published; under the earlier gate it still is."""
    require_shared_data("the home / hotel cross-place case")
    from regor_ros.bench.datasets import load_pairs
    pairs = {p.name: p for p in load_pairs(DATA / "pairs_scenes", None)}
    hotel, home = pairs["3dmatch_hotel_umd3_28_31"].moved(4), pairs["3dmatch_home_at_53_57"]
    result = register(home.tgt, hotel.src, RegorConfig.preset("indoor").replace({"seed": 4}),
                      source_viewpoint=home.tgt_viewpoint, target_viewpoint=hotel.src_viewpoint)
    assert not result.accepted
    earlier = register(home.tgt, hotel.src, RegorConfig.preset("indoor").replace({**EARLIER_INDOOR, "seed": 4}),
                       source_viewpoint=home.tgt_viewpoint, target_viewpoint=hotel.src_viewpoint)
    assert earlier.accepted


def test_reverse_check_rejects_a_room_of_another_place_and_keeps_a_true_pose(kitchen_pair):
    hotel, sensor = hotel_scan_moved_by_benchmark_motion_3()
    kitchen = load_pair("3dmatch_redkitchen_0_5_ds")[1]
    cfg = RegorConfig().replace({**EARLIER_INDOOR, "seed": 3, "max_free_space_violation": 1.0, "reverse_check": True})
    checked = register(hotel, kitchen, cfg, source_viewpoint=sensor)
    assert not checked.accepted and "reverse_check" in checked.reason
    src, tgt, T_gt, _ = kitchen_pair
    true_pose = register(src, tgt, RegorConfig().replace({"reverse_check": True}))
    assert true_pose.accepted and is_success(true_pose.transform, T_gt, "indoor")


def degenerate_cases():
    rng = np.random.default_rng(0)
    plane = np.c_[rng.uniform(-2, 2, (20000, 2)), np.zeros(20000)]
    line = np.c_[np.linspace(0, 10, 5000), np.zeros((5000, 2))]
    src, tgt, T_gt, _ = moved_pair("3dmatch_redkitchen_5_6_ds", 1)
    in_target = src @ T_gt[:3, :3].T + T_gt[:3, 3]
    cut = np.median(tgt[:, 0])
    return {"plane": (plane, plane + [0.3, 0.2, 0.0]),
            "line": (line, line),
            "no overlap": (src[in_target[:, 0] < cut - 0.4], tgt[tgt[:, 0] > cut + 0.4]),
            "random target": (src, rng.uniform(tgt.min(0), tgt.max(0), (20000, 3)))}


@pytest.mark.parametrize("case", ["plane", "line", "no overlap", "random target"])
def test_degenerate_geometry_is_not_accepted(case):
    src, tgt = degenerate_cases()[case]
    result = register(src, tgt, RegorConfig())
    assert not result.accepted and result.reason


def test_a_single_repeated_point_is_refused_with_a_reason():
    with pytest.raises(RegistrationError, match="1 points after downsampling"):
        register(np.ones((1000, 3)), np.ones((1000, 3)), RegorConfig())
    with pytest.raises(RegistrationError, match=r"too few points to register \(3;"):
        register(np.eye(3), np.ones((1000, 3)), RegorConfig())


def test_a_million_point_cloud_is_downsampled_and_registered():
    src, tgt, T_gt, kind = moved_pair("3dmatch_redkitchen_5_6_ds", 8)
    rng = np.random.default_rng(1)
    copies = -(-1_000_000 // len(src))
    dense = (np.repeat(src, copies, axis=0) + rng.normal(scale=0.003, size=(copies * len(src), 3)))[:1_000_000]
    result = register(dense, tgt, RegorConfig())
    print(f"\n1,000,000-point source registered in {result.timings['total']:.2f} s "
          f"(features {result.timings['features']:.2f} s)")
    assert is_success(result.transform, T_gt, kind) and result.accepted


def test_the_authors_quirks_can_be_reproduced(kitchen_pair):
    src, tgt, T_gt, kind = kitchen_pair
    cfg = RegorConfig().replace({"reproduce_fs_tcd_quirk": True, "reproduce_ctc_padding_bug": True,
                                 "subset": "random", "dedupe_hypotheses": False,
                                 "ranking": "inliers", "seed_ratio": 0.2, "nms_radius": 0.1})
    result = register(src, tgt, cfg)
    assert is_success(result.transform, T_gt, kind)


def test_plane_refinement_brings_a_sparse_scan_pair_from_a_metre_off_to_centimetres():
    """Two Livox Avia scans 11 m apart (HKU campus): the point level pairs keypoints up to tau_e
    = 1.2 m apart and settles about a metre off; point-to-plane lands on the truth. (Whether the
    gate publishes it is not this test's subject: since the minimal sample is discounted, its 7
    independent agreeing matches of 216 are what chance gives in this search, and it is withheld.)
    The normals keep the solver's signs: facing each scan's sensor, this pair is not found at all
    (measured: 123 deg off, withheld), a loss noted where the outdoor preset turned them."""
    require_shared_data("the Avia scan pair")
    folder = DATA / "maps" / "fastlio_avia_hku2" / "queries"
    src, tgt = np.load(folder / "scan_000005" / "scan.npy"), np.load(folder / "scan_000057" / "scan.npy")
    T_gt = np.linalg.inv(np.loadtxt(folder / "scan_000057" / "gt.txt")) @ np.loadtxt(folder / "scan_000005" / "gt.txt")
    cfg = RegorConfig.preset("outdoor").replace({"features.normals_toward_sensors": False})
    point = register(src, tgt, cfg.replace({"estimation.plane_refinement": False}))
    plane = register(src, tgt, cfg)
    assert is_success(plane.transform, T_gt, "outdoor")
    assert translation_error(plane.transform, T_gt) < 0.2 < translation_error(point.transform, T_gt)
    assert rotation_error_deg(plane.transform, T_gt) < rotation_error_deg(point.transform, T_gt)


def test_a_plane_refinement_that_slides_off_the_surfaces_keeps_the_point_level_pose(kitchen_pair, monkeypatch):
    """A refinement is kept only when it puts at least as many keypoints on the target's surfaces
    (within a voxel) as the point-level pose: one that slid 2 tau_e away found another pose."""
    import regor_ros.core.estimate as estimate
    src, tgt, _, _ = kitchen_pair
    cfg = RegorConfig()
    point = register(src, tgt, cfg.replace({"estimation.plane_refinement": False}))
    slid = np.eye(4)
    slid[:3, 3] = [2 * cfg.estimation.inlier_threshold, 0.0, 0.0]
    monkeypatch.setattr(estimate, "plane_refine", lambda T, *args, **kwargs: slid @ T)
    kept = register(src, tgt, cfg.replace({"estimation.plane_refinement": True}))
    np.testing.assert_array_equal(kept.transform, point.transform)
    assert kept.num_inliers == point.num_inliers and kept.accepted == point.accepted
