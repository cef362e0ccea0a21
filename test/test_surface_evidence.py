"""The surfaces' test against chance (core/gate/surface_evidence.py): a right pose of a sparse scan
lays its cells on the map far beyond what wrong poses refined there do; a scan of another place
does not; either test against chance carries a pose (judge)."""
import numpy as np
from conftest import DATA, EARLIER_INDOOR, require_shared_data

from regor_ros.bench.datasets import load_sequence
from regor_ros.core import Figures, RegorConfig, judge, prepare_cloud, register
from regor_ros.core.estimate import plane_refine, plane_thresholds, point_refine
from regor_ros.core.gate.surface_evidence import surface_evidence
from regor_ros.core.metrics import is_success

OUTDOOR = RegorConfig.preset("outdoor")
AGAINST_A_MAP = OUTDOOR.replace({"features.remove_ground": False})   # a scan keeps its ground against a map
HYPOTHESES = 1250   # what the search tries outdoors (initial.seeds' hypotheses)


def evidence_at(T, source, target):
    """The test at ``T`` refined as the estimator refines (point level, then planes), all decoys."""
    est, voxel = OUTDOOR.estimation, OUTDOOR.features.voxel_size
    T = point_refine(T, source.points, target.neighbours, est.inlier_threshold, est.max_iterations).transform
    T = plane_refine(T, source.points, target.neighbours, target.normals,
                     plane_thresholds(est.inlier_threshold, voxel), voxel)
    return surface_evidence(T, source, target, OUTDOOR, HYPOTHESES, chance_explains=lambda _: False)


def test_a_sparse_scans_right_pose_is_carried_by_its_surfaces(avia_map):
    """scan_000259 thinned to every 4th point: 2-3 independent agreeing feature matches, but its
    cells lie on the map's surfaces where no wrong pose refined there gets as many."""
    target, queries = avia_map
    query = queries["scan_000259"]
    source = prepare_cloud(query.scan[::4], OUTDOOR, "scan", viewpoint=(0, 0, 0))
    evidence = evidence_at(query.truth, source, target)
    assert 0.95 * evidence.cells <= evidence.agreeing <= evidence.cells and evidence.cells > 50
    assert evidence.decoys >= 3 and evidence.chance < 0.95
    assert evidence.log10_false_alarms < -3


def test_another_place_is_not_carried_by_its_surfaces(avia_map):
    """A MulRan scan placed in the Avia map at its registered pose fits no better than decoys there.
    (Avia scan 133, which once registered slid along a corridor with its cells on the map's
    surfaces, is found since the map keeps its ground: the slide no longer arises here.)"""
    target, _ = avia_map
    _, _, elsewhere = load_sequence(DATA / "maps" / "scaloam_mulran_kaist03")
    wrong = register(elsewhere[0].scan, target, OUTDOOR)
    assert not wrong.accepted
    stranger = prepare_cloud(elsewhere[0].scan, AGAINST_A_MAP, "scan", viewpoint=(0, 0, 0))
    assert evidence_at(wrong.transform, stranger, target).log10_false_alarms > 0


def test_a_wrong_indoor_pose_is_not_carried_by_its_surfaces():
    """3DMatch hotel_umd3 33 -> 30 (3DLoMatch): a wrong pose that fails the feature test (10^0.2)
    with most of its few cells on the other fragment's surfaces; indoor decoys do as well. (Before
    each cell was judged by one keypoint, more cells could agree than there were, and it passed.)
    Both sensors see through its surfaces (5 % and 3 %), which withholds it too; that check is
    lifted so that nothing but the tests against chance does, and the surfaces are measured."""
    require_shared_data("the surface evidence tests")
    folder = DATA / "threedmatch"
    scene = next(p.name for p in folder.iterdir() if p.name.startswith("sun3d-hotel_umd"))
    source, target = np.load(folder / scene / "33.npy"), np.load(folder / scene / "30.npy")
    config = RegorConfig.preset("indoor").replace({**EARLIER_INDOOR, "max_free_space_both_sides": 1.0})
    result = register(source, target, config)
    assert not result.accepted and result.verdict.failed == "max_false_alarms", result.reason
    figures = result.figures
    assert figures.surface_cells_agreeing <= figures.surface_cells and figures.surface_chance <= 1
    assert figures.surface_log10_false_alarms > 0


def figures(features: float, surfaces: float, feature_inliers: int = 60, target_side: float = 0.0) -> Figures:
    """A pose every check passes but those against chance (log10 false alarms of each test)."""
    return Figures(num_inliers=500, fitness=0.5, surface_agreement=0.99, log10_false_alarms=features,
                   independent_agreeing=2, feature_inliers=feature_inliers, free_space_source=0.0,
                   free_space_target=target_side,
                   surface_log10_false_alarms=surfaces, surface_cells=124, surface_cells_agreeing=123,
                   surface_chance=0.8)


def test_either_test_against_chance_carries_a_pose_and_the_verdict_says_which():
    gate = OUTDOOR.acceptance
    assert judge(figures(-4.0, float("nan")), gate).carried_by == "feature matches"
    carried = judge(figures(2.5, -5.6), gate)
    assert carried.accepted and carried.carried_by == "surfaces"
    for surfaces in (float("nan"), 0.4):
        withheld = judge(figures(2.5, surfaces), gate)
        assert not withheld.accepted and withheld.failed == "max_false_alarms" and withheld.carried_by == ""
    assert "123 of 124 independent cells" in judge(figures(2.5, 0.4), gate).reason
    assert "cells" not in judge(figures(2.5, float("nan")), gate).reason   # not measured: not told


def test_a_pose_its_surfaces_carry_needs_no_feature_count_unless_free_space_was_checked_one_way():
    """min_feature_inliers was fitted on poses the feature matches carry; a sparse scan's right pose
    has a few even where its surfaces prove it. Without free space from both sides the features
    must still stand on their own (min_feature_inliers_partial)."""
    gate = OUTDOOR.acceptance
    few = gate.min_feature_inliers - 3
    assert judge(figures(2.5, -5.6, few), gate).accepted
    withheld = judge(figures(2.5, 0.4, few), gate)
    assert not withheld.accepted and withheld.failed == "max_false_alarms"
    assert judge(figures(-4.0, float("nan"), few), gate).failed == "min_feature_inliers"
    one_way = judge(figures(2.5, -5.6, few, target_side=float("nan")), gate)
    assert one_way.failed == "min_feature_inliers" and "min_feature_inliers_partial" in one_way.reason


def test_a_sparse_scan_with_fewer_agreeing_matches_than_the_count_is_published_on_its_surfaces(avia_map):
    """scan_000221 thinned to every 4th point is registered 0.1 deg / 2 cm from the truth with
    fewer agreeing feature matches than min_feature_inliers (measured: 0-2); its cells on the map's
    surfaces carry it."""
    target, queries = avia_map
    query = queries["scan_000221"]
    result = register(query.scan[::4], target, OUTDOOR)
    assert is_success(result.transform, query.truth, "outdoor")
    assert result.feature_inliers < OUTDOOR.acceptance.min_feature_inliers
    assert result.accepted and result.verdict.carried_by == "surfaces", result.reason


def test_a_wrong_pose_with_as_few_agreeing_matches_is_not_carried_by_its_surfaces():
    """The revisit loop's scan_000200 alone lands at a lookalike, degrees and metres off, with a
    few agreeing feature matches (4 independent: chance gives that much, whichever lookalike the
    search's candidates lead it to); its surfaces, on which wrong poses refined there lie nearly as
    much, do not carry it either."""
    require_shared_data("the surface evidence tests")
    cloud, trajectory, queries = load_sequence(DATA / "revisit" / "avia_hku2_loop")
    target = prepare_cloud(cloud, OUTDOOR, "map", trajectory=trajectory)
    query = {q.id: q for q in queries}["scan_000200"]
    result = register(query.scan, target, OUTDOOR)
    assert not is_success(result.transform, query.truth, "outdoor")
    assert result.figures.log10_false_alarms > np.log10(OUTDOOR.acceptance.max_false_alarms)
    assert not result.accepted and result.verdict.failed == "max_false_alarms", result.reason
    assert not result.verdict.carried_by
    # the surfaces are measured only where they could change the verdict: a rival as well
    # supported withholds this pose too, or the surfaces' test ran and failed
    withheld_anyway = result.ambiguity is not None and result.ambiguity > OUTDOOR.acceptance.max_ambiguity
    assert withheld_anyway or result.figures.surface_log10_false_alarms > 0


def test_the_pipeline_measures_the_surfaces_only_when_they_can_change_the_verdict(avia_map):
    target, queries = avia_map
    query = queries["scan_000259"]
    alone = register(query.scan, target, OUTDOOR)          # carried by its feature matches
    assert alone.accepted and alone.verdict.carried_by == "feature matches"
    assert np.isnan(alone.figures.surface_log10_false_alarms)
    thinned = register(query.scan[::4], target, OUTDOOR)
    assert is_success(thinned.transform, query.truth, "outdoor")
    assert thinned.evidence.log10_false_alarms > 0          # the features alone would withhold it
    assert thinned.accepted and thinned.verdict.carried_by == "surfaces", thinned.reason
    assert thinned.summary().carried_by == "surfaces"
