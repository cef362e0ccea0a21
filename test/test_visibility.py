"""The free-space check: synthetic rooms with known answers, one-sided checks, real cross-place poses."""
from dataclasses import replace

import numpy as np
import pytest
from conftest import DATA, EARLIER_INDOOR, load_pair, load_threedmatch, require_shared_data

from regor_ros.core import RegistrationError, RegorConfig, prepare_cloud, register, rotation_error_deg
from regor_ros.core.config import ConfigError
from regor_ros.core.gate.figures import Figures
from regor_ros.core.gate.judge import Rules, judge
from regor_ros.core.gate.rivals import rivals as refined_rivals
from regor_ros.core.gate.visibility import free_space_figures, visibility_figures
from regor_ros.core.geometry import transform_points
from regor_ros.core.metrics import random_rigid_motion
from regor_ros.core.pipeline import refined_from
from regor_ros.core.range_image import RangeImage
from regor_ros.core.viewpoint import ORIGIN, parse_viewpoint

SCENES = DATA / "pairs_scenes"

INDOOR = RegorConfig.preset("indoor")
def box_surface(low, high, spacing, rng, faces=("x-", "x+", "y-", "y+", "z-", "z+")):
    """Points on the chosen faces of an axis-aligned box."""
    low, high = np.asarray(low, float), np.asarray(high, float)
    parts = []
    for face in faces:
        axis, side = "xyz".index(face[0]), face[1]
        others = [a for a in range(3) if a != axis]
        n = int(np.prod(high[others] - low[others]) / spacing ** 2)
        pts = rng.uniform(low, high, (n, 3))
        pts[:, axis] = low[axis] if side == "-" else high[axis]
        parts.append(pts)
    return np.vstack(parts)


def room(spacing=0.02, seed=0):
    """A 6 x 3.5 m room as a depth camera sees it (floor and walls, no ceiling) with a table and a
    cabinet that break its symmetry."""
    rng = np.random.default_rng(seed)
    shell = box_surface((-3.0, -1.75, 0.0), (3.0, 1.75, 2.5), spacing, rng, ("x-", "x+", "y-", "y+", "z-"))
    table = box_surface((1.5, 0.5, 0.0), (2.5, 1.3, 0.75), spacing, rng, ("x-", "y-", "z+"))
    cabinet = box_surface((-2.9, -1.7, 0.0), (-2.3, -1.2, 1.8), spacing, rng, ("x+", "y+", "z+"))
    return np.vstack([shell, table, cabinet])


def matched(T, source):
    """Feature matches that all agree with T (so the feature check passes)."""
    return source.points, transform_points(T, source.points), np.ones(len(source), dtype=bool)


def verdict_on_visibility(T, source, target):
    """The gate's verdict when every figure but free space, sides and the symmetric rivals passes
    (measured on the pose as given, the rivals refined as the pipeline does)."""
    visibility = visibility_figures(T, source, target, INDOOR.acceptance, np.arange(len(target)))
    overlap = (source.points, target.points, target.normals)
    rivals, _ = refined_rivals(T, overlap, matched(T, source), [], source, target, INDOOR,
                               Rules(INDOOR.acceptance).contends,
                               lambda pose: refined_from(pose, source, target, INDOOR, None))
    figures = Figures(num_inliers=5000, fitness=0.9, constrained=True, surface_agreement=1.0,
                      log10_false_alarms=-50.0, independent_agreeing=100, feature_inliers=len(source),
                      rivals=rivals, **visibility.as_figures())
    return judge(figures, INDOOR.acceptance), figures


def turn_about_z(degrees, centre=(0.0, 0.0, 0.0)):
    a = np.radians(degrees)
    T = np.eye(4)
    T[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    T[:3, 3] = centre - T[:3, :3] @ centre
    return T


@pytest.fixture(scope="module")
def rooms():
    """Two scans of one 6 x 4 m room from sensors 1.2 m up, the source's frame turned and moved."""
    walls = room()
    source_sensor, target_sensor = np.array([0.8, -0.3, 1.2]), np.array([-1.0, 0.5, 1.2])
    motion = turn_about_z(30.0)
    motion[:3, 3] += [0.4, -0.2, 0.0]
    source_points = transform_points(motion, walls)
    source = prepare_cloud(source_points, INDOOR, viewpoint=transform_points(motion, source_sensor[None])[0])
    target = prepare_cloud(room(seed=1), INDOOR, viewpoint=target_sensor)
    return source, target, np.linalg.inv(motion)


def test_true_pose_of_a_room_sees_no_surface_in_free_space(rooms):
    source, target, T_true = rooms
    figures = visibility_figures(T_true, source, target, INDOOR.acceptance)
    assert figures.free_space_source < 0.02 and figures.free_space_target < 0.02
    verdict, _ = verdict_on_visibility(T_true, source, target)
    assert verdict.accepted, verdict.reason


def test_room_turned_90_degrees_is_rejected_by_visibility_alone(rooms):
    source, target, T_true = rooms
    wrong = turn_about_z(90.0, centre=np.array([0.0, 0.0, 1.25])) @ T_true
    # every other check is given passing figures: only free space can reject it
    verdict, figures = verdict_on_visibility(wrong, source, target)
    assert not verdict.accepted and verdict.failed == "max_free_space_violation"
    assert "saw through" in verdict.reason and "max_free_space_violation" in verdict.reason
    assert figures.worst_free_space > 0.1   # the true pose: under 0.02


def test_a_map_is_seen_from_the_pose_and_no_viewpoint_on_either_side_skips_the_check(rooms):
    source, target, T_true = rooms
    map_like = prepare_cloud(room(seed=1), INDOOR, viewpoint=None)
    wrong = turn_about_z(90.0, centre=np.array([0.0, 0.0, 1.25])) @ T_true
    both = visibility_figures(wrong, source, map_like, INDOOR.acceptance)
    # the map's side: the room seen from where the wrong pose puts the source sensor
    assert both.free_space_source > 0.1 and both.free_space_target > 0.1 and both.map_seen > 0.5
    right = free_space_figures(T_true, source, map_like, INDOOR.acceptance)
    assert right.free_space_target < INDOOR.acceptance.max_free_space_violation and right.both_sides
    blind = prepare_cloud(transform_points(np.linalg.inv(T_true), room()), INDOOR, viewpoint=None)
    unknown = free_space_figures(wrong, blind, map_like, INDOOR.acceptance)
    assert np.isnan(unknown.worst_free_space)
    assert verdict_on_visibility(wrong, blind, map_like)[0].accepted


def test_empty_bins_are_unknown_not_free():
    image = RangeImage.build(np.array([[2.0, 0.0, 0.0], [2.0, 0.02, 0.0]]), (0, 0, 0), 1.0)
    seen, inside = image.violations(np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]]), 0.1, 0.0)
    assert (seen, inside) == (1, 1)   # only the ray the sensor measured is known free


def test_viewpoints_are_parsed_and_checked():
    assert parse_viewpoint("auto", "v") == (0.0, 0.0, 0.0)
    assert parse_viewpoint("none", "v") is None
    assert parse_viewpoint("[1, 2.5, -3]", "v") == (1.0, 2.5, -3.0)
    for bad in ("1, 2", "a, b, c", "1, 2, nan"):
        with pytest.raises(ConfigError, match="x, y, z"):
            parse_viewpoint(bad, "source_viewpoint")
    src, tgt, _, _ = load_pair("3dmatch_redkitchen_5_6_ds")
    with pytest.raises(RegistrationError, match="viewpoint"):
        register(src, tgt, INDOOR, source_viewpoint=(0, 0))


def test_a_map_without_viewpoint_still_registers_and_is_checked_from_the_scans_side(kitchen_pair):
    src, tgt, T_gt, kind = kitchen_pair
    target = prepare_cloud(tgt, INDOOR, viewpoint=None)
    result = register(src, target, INDOOR, source_viewpoint=(0, 0, 0))
    assert result.accepted, result.reason
    assert result.visibility.free_space_source is not None and result.visibility.free_space_source < 0.1
    # a fragment of a room as the map: too little of the scan lands on what it holds to count
    assert result.visibility.map_seen < INDOOR.acceptance.map_view_min_seen
    assert result.visibility.free_space_target is None and not result.figures.both_sides
    assert result.summary().figures.worst_free_space == result.visibility.free_space_source


def scenes_pair_source(name, motion_seed):
    """A pairs_scenes source moved by the benchmark's motion ``motion_seed``, and its sensor."""
    import json
    listing = [p["name"] for p in json.loads((SCENES / "pairs.json").read_text())]
    motion = random_rigid_motion([motion_seed, listing.index(name)])
    return transform_points(motion, np.load(SCENES / name / "src.npy")), motion[:3, 3]


def test_rooms_of_two_places_put_back_to_back_are_rejected_by_the_opposite_sides_check():
    """A hotel room registered onto a study room, their shared wall seen from its two sides: no
    surface of either lies in the other's free space, yet the pose is wrong (benchmark, motion 2)."""
    require_shared_data("this cross-place pair")
    hotel, sensor = scenes_pair_source("3dmatch_hotel_uc_2_34", 2)
    study = np.load(SCENES / "3dmatch_studyroom_27_32" / "tgt.npy")
    cfg = INDOOR.replace({"seed": 2})
    # the slide check (gate/slide.py), the rivals' (gate/rivals.py: a quarter turn fits as well)
    # and chance (its few agreeing matches) also withhold this pose: off, to see the others pass
    blind = register(hotel, study, cfg.replace({"max_opposite_sides": 1.0, "min_feature_inliers": 0,
                                                "min_weakest_support": 0.0, "max_ambiguity": 1.0,
                                                "max_false_alarms": 1e12}),
                     source_viewpoint=sensor)
    assert blind.accepted, blind.reason   # every other check passes
    assert blind.figures.worst_free_space < 0.01
    checked = register(hotel, study, cfg.replace({"min_feature_inliers": 0, "max_false_alarms": 1e12}),
                       source_viewpoint=sensor)
    assert not checked.accepted and "opposite sides" in checked.reason
    assert checked.visibility.opposite_sides > 0.9


def test_against_a_cloud_without_viewpoint_features_must_stand_on_their_own():
    """A home fragment on a kitchen fragment (benchmark motion 6): 71 feature matches agree, and
    only the kitchen sensor's free space shows it wrong. Without the kitchen's viewpoint (as for a
    map) the check sees one side, and the partial feature threshold has to reject it."""
    require_shared_data("this cross-place pair")
    from regor_ros.bench.datasets import load_pairs
    pairs = {p.name: p for p in load_pairs(DATA / "pairs", None)}
    home, kitchen = pairs["3dmatch_home_at_38_41_ds"].moved(6), pairs["3dmatch_redkitchen_21_34_ds"]
    # the point-level pose (refined point to plane, 51 agree: the feature count alone rejects it)
    cfg = INDOOR.replace({**EARLIER_INDOOR, "seed": 6, "estimation.plane_refinement": False})
    both = register(home.src, kitchen.tgt, cfg, source_viewpoint=home.src_viewpoint)
    assert not both.accepted and "lies in space" in both.reason
    assert both.feature_inliers >= cfg.acceptance.min_feature_inliers
    as_map = prepare_cloud(kitchen.tgt, cfg, viewpoint=None)
    one_sided = register(home.src, as_map, cfg, source_viewpoint=home.src_viewpoint)
    assert not one_sided.figures.both_sides and one_sided.summary().as_json()["figures"]["both_sides"] is False
    assert not one_sided.accepted and "min_feature_inliers_partial" in one_sided.reason
    lenient = cfg.replace({"min_feature_inliers_partial": cfg.acceptance.min_feature_inliers})
    assert register(home.src, as_map, lenient, source_viewpoint=home.src_viewpoint).accepted


def test_two_rooms_without_viewpoints_need_the_partial_count_fitted_on_such_runs():
    # 3DMatch studyroom 65 -> 21 with neither sensor position given (regor-bench --no-viewpoints):
    # the search turns the room by 93 deg, 4 m off, and 98 matches agree. No free space can show
    # it wrong; the earlier partial count (95) published it, the count leave one scene out fits
    # (150) does not (results/no_viewpoints/: 25 gross wrong poses on the lists at 95, 10 at 150)
    src, tgt, T = load_threedmatch("studyroom", 65, 21)
    unseen = register(src, tgt, INDOOR, source_viewpoint=None, target_viewpoint=None)
    assert rotation_error_deg(unseen.transform, T) > 80 and not unseen.figures.both_sides
    assert not unseen.accepted and "min_feature_inliers_partial=150" in unseen.reason
    earlier = INDOOR.replace({"min_feature_inliers_partial": 95})
    assert register(src, tgt, earlier, source_viewpoint=None, target_viewpoint=None).accepted


def test_a_box_rooms_quarter_turn_seen_through_from_both_sides_is_withheld():
    # 3DMatch studyroom 39 -> 0 (3DLoMatch), the indoor gate of the time: the search's pose turns
    # the room by 88 deg onto a larger overlap than the truth's, with 126 agreeing feature matches.
    # Each sensor sees 4-5 % of the other cloud in its free space, under the one-sided bound (a
    # fused fragment's other views leave correct poses up to 6 % on one side); both at once is no
    # artefact of one sensor: the surfaces pass through each other
    src, tgt, T_gt = load_threedmatch("studyroom", 39, 0)
    config = RegorConfig.preset("indoor").replace({**EARLIER_INDOOR, "seed": 0})
    source, target = (prepare_cloud(cloud, config, viewpoint=ORIGIN) for cloud in (src, tgt))
    result = register(source, target, config)
    assert rotation_error_deg(result.transform, T_gt) > 80
    gate, sides = config.acceptance, (result.visibility.free_space_source, result.visibility.free_space_target)
    assert max(sides) <= gate.max_free_space_violation and min(sides) > gate.max_free_space_both_sides
    assert not result.accepted and result.verdict.failed == "max_free_space_both_sides", result.reason
    assert result.reason.startswith("both sensors saw through the other cloud's surfaces")
    # the verification's pick (estimation.visible_candidates) holds a place to the same checks (it
    # reads free space without the pose's uncertainty: each side's bound is lifted to tell them apart)
    loose = replace(gate, max_free_space_violation=0.1)
    figures = free_space_figures(result.transform, source, target, loose)
    assert not Rules(loose).free_space_passes(figures)
    assert Rules(replace(loose, max_free_space_both_sides=1.0)).free_space_passes(figures)


def test_a_pose_seen_through_from_one_side_only_passes_the_both_sides_check():
    def figures(source_side, target_side):
        return Figures(num_inliers=500, fitness=0.5, surface_agreement=1.0, log10_false_alarms=-10.0,
                       independent_agreeing=50, feature_inliers=200, free_space_source=source_side,
                       free_space_target=target_side)
    gate = replace(INDOOR.acceptance, max_free_space_violation=0.06)   # a fused fragment's one-sided artefacts
    assert judge(figures(0.05, 0.0), gate).accepted
    assert judge(figures(0.05, float("nan")), gate).accepted     # a side not measured shows nothing
    assert judge(figures(0.03, 0.03), gate).failed == "max_free_space_both_sides"
    assert judge(figures(0.03, 0.03), replace(gate, max_free_space_both_sides=1.0)).accepted
