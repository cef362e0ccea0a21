"""The gravity prior on real ground-vehicle LiDAR (MulRan, OS1-64 on a car: its z axis is up,
measured tilt between the two scans 0.35 deg against the SLAM truth)."""
import numpy as np
import pytest
from conftest import DATA, require_shared_data
from scipy.spatial.transform import Rotation

from regor_ros.bench.datasets import UP_Z, Pair
from regor_ros.core import RegorConfig, prepare_cloud, register
from regor_ros.core.config import ConfigError, parse_up
from regor_ros.core.gate.figures import Figures
from regor_ros.core.gate.judge import judge
from regor_ros.core.gate.measure import gravity_figures
from regor_ros.core.gravity import GravityPrior
from regor_ros.core.metrics import random_rigid_motion, rotation_error_deg, translation_error

PAIR = "mulran_riv02_048_to_044"  # 12 m apart, 72 % overlap: Regor registers it with or without the prior


@pytest.fixture(scope="module")
def ground_pair():
    require_shared_data("the gravity prior tests")
    folder = DATA / "pairs_hard" / PAIR
    return np.load(folder / "src.npy"), np.load(folder / "tgt.npy"), np.loadtxt(folder / "gt.txt")


def level(config: RegorConfig, source_up, height_tolerance=0.5) -> RegorConfig:
    return config.replace({"gravity.source_up": " ".join(map(str, source_up)), "gravity.target_up": "0 0 1",
                           "gravity.height_tolerance": height_tolerance})


def tipped(T: np.ndarray, degrees: float) -> np.ndarray:
    """T turned about the target's x axis through the source's sensor."""
    a = np.radians(degrees)
    turn = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    out = T.copy()
    out[:3, :3] = turn @ T[:3, :3]
    return out


def test_up_directions_are_parsed_or_named_in_the_error():
    assert np.allclose(parse_up("0, 0, 2"), [0, 0, 1])
    assert parse_up("unknown") is None
    assert GravityPrior.of(RegorConfig().gravity) is None          # off by default: today's behaviour
    with pytest.raises(ConfigError, match="gravity.source_up"):
        RegorConfig().replace({"gravity.source_up": "0 0"})
    with pytest.raises(ConfigError, match="gravity.target_up"):
        RegorConfig().replace({"gravity.target_up": "0 0 0"})


def test_clamp_moves_a_rotation_onto_the_cone_and_leaves_one_inside_alone():
    prior = GravityPrior(np.array([0.0, 0, 1]), np.array([0.0, 0, 1]), 10.0, 0.0, 10.0)
    inside, outside = tipped(np.eye(4), 6.0)[:3, :3], tipped(np.eye(4), 30.0)[:3, :3]
    clamped = prior.clamp(np.stack([inside, outside]))
    assert np.allclose(clamped[0], inside)
    assert prior.tilt_deg(clamped[1]) == pytest.approx(10.0)
    assert rotation_error_deg(np.pad(clamped[1], (0, 1)), np.pad(outside, (0, 1))) == pytest.approx(20.0)
    upside_down = prior.clamp(tipped(np.eye(4), 180.0)[:3, :3])
    assert prior.tilt_deg(upside_down) == pytest.approx(10.0)


def test_a_level_pose_passes_and_a_tipped_over_one_is_rejected_with_the_reason(ground_pair):
    src, tgt, T = ground_pair
    config = level(RegorConfig.preset("outdoor"), UP_Z)
    source = prepare_cloud(src, config, viewpoint=[0, 0, 0])
    target = prepare_cloud(tgt, config, viewpoint=[0, 0, 0])
    prior = GravityPrior.of(config.gravity)

    def verdict(pose):   # every figure but gravity's passes
        figures = Figures(num_inliers=5000, fitness=0.9, constrained=True, surface_agreement=1.0,
                          log10_false_alarms=-50.0, independent_agreeing=100, feature_inliers=1000,
                          **gravity_figures(pose, prior, source, target))
        return judge(figures, config.acceptance)

    assert verdict(T).accepted
    tipped_over = verdict(tipped(T, 25.0))
    assert tipped_over.failed == "gravity_tilt" and "gravity.max_tilt=10" in tipped_over.reason
    lifted = T.copy()
    lifted[2, 3] += 4.0  # 12 m away: 0.5 m plus 12 m x tan(10 deg) = 2.6 m allowed
    out_of_band = verdict(lifted)
    assert out_of_band.failed == "gravity_height" and "gravity.height_tolerance" in out_of_band.reason
    assert "12.1 m away (allowed 2.64 m" in out_of_band.reason
    assert prior.allows(np.stack([T, lifted, tipped(T, 25.0)]), source, target).tolist() == [True, False, False]


def test_registration_with_the_prior_stays_inside_it_and_finds_the_pose(ground_pair):
    src, tgt, T = ground_pair
    M = random_rigid_motion([3, 1])  # the source turned any way: its up turns with it
    moved = src @ M[:3, :3].T + M[:3, 3]
    truth = T @ np.linalg.inv(M)
    config = level(RegorConfig.preset("outdoor"), M[:3, :3] @ UP_Z)
    result = register(moved, tgt, config, source_viewpoint=M[:3, 3])
    assert result.accepted, result.reason
    assert rotation_error_deg(result.transform, truth) < 5 and translation_error(result.transform, truth) < 0.6
    assert GravityPrior.of(config.gravity).tilt_deg(result.transform[:3, :3]) <= 10.0


def test_a_wrong_up_direction_cannot_give_a_published_pose(ground_pair):
    """Told the sensor lies on its side (x up) with a 5 deg bound, no pose inside the cone fits:
    the true one is 90 deg outside it."""
    src, tgt, _ = ground_pair
    config = level(RegorConfig.preset("outdoor"), [1.0, 0.0, 0.0]).replace({"gravity.max_tilt": 5.0})
    result = register(src, tgt, config)
    assert not result.accepted
    assert GravityPrior.of(config.gravity).tilt_deg(result.transform[:3, :3]) <= 5.0 + 1e-6


def test_an_up_off_by_more_than_the_cone_holds_the_pose_on_its_edge_and_it_is_withheld(ground_pair):
    """The scan's up given 14 deg off the truth's (an IMU read while turning), with the default
    10 deg bound: the truth lies outside the cone, the pose found is held on its edge, where the
    prior put it, and the gate says so rather than publish a pose degrees off."""
    src, tgt, T = ground_pair
    true_up = T[:3, :3].T @ np.array([0.0, 0.0, 1.0])
    off = np.cross(true_up, [1.0, 0.0, 0.0])
    wrong_up = Rotation.from_rotvec(np.radians(14.0) * off / np.linalg.norm(off)).apply(true_up)
    config = level(RegorConfig.preset("outdoor"), wrong_up, height_tolerance=0.0)
    result = register(src, tgt, config, source_viewpoint=[0, 0, 0], target_viewpoint=[0, 0, 0])
    prior = GravityPrior.of(config.gravity)
    assert prior.held_at_edge(result.transform[:3, :3])
    assert not result.accepted and result.verdict.failed == "gravity_tilt"
    assert "held on the edge the prior allows: the up given is off by more than that" in result.reason
    assert not prior.held_at_edge(T[:3, :3])   # 14 deg off the up given: outside the cone, not on its edge


def test_the_benchmark_turns_the_source_up_with_its_random_motion(ground_pair):
    src, tgt, T = ground_pair
    pair = Pair(3, PAIR, "outdoor", src, tgt, T, np.zeros(3), np.zeros(3), UP_Z, UP_Z)
    moved = pair.moved(5)
    before = GravityPrior.of(pair.configured(RegorConfig.preset("outdoor")).gravity).tilt_deg(T[:3, :3])
    after = GravityPrior.of(moved.configured(RegorConfig.preset("outdoor")).gravity).tilt_deg(moved.T_gt[:3, :3])
    assert after == pytest.approx(before, abs=1e-6)
    assert before < 1.0   # the measured tilt of this pair: 0.35 deg
