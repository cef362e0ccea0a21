"""Every tunable of the registration core, in one dataclass tree.

This module is the single source of truth: the ROS node declares its parameters from it, the
command line's ``--set`` overrides go through it, and the YAML presets in ``config/`` are generated
from it. Each field carries a description and a valid range in its metadata.

One scale: the lengths that follow the sensor's resolution (radii, thresholds, the free-space
margin) are set in voxels (``<name>_voxels``, multiples of ``features.voxel_size``, as KISS-Matcher
sets its radii), so a preset is a voxel and a handful of choices, and one knob fits a new sensor.
The code reads each in metres under its own name (``<name>``), derived and never set: a derived
length is rounded to the picometre, so a multiple written as a decimal gives the decimal it means
(3 x 0.3 m is 0.9 m, not the float below it).
"""
from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import ConfigError
from .geometry import parse_numbers


def param(default: Any, description: str, low: float | None = None,
           high: float | None = None):
    """A dataclass field with its description and inclusive valid range."""
    meta = {"description": description, "range": (low, high)}
    if isinstance(default, list):
        return field(default_factory=lambda: list(default), metadata=meta)
    return field(default=default, metadata=meta)


LENGTH_DIGITS = 12   # a derived length is rounded to the picometre (the module's docstring)


def length(metres: float) -> Any:
    """A length in metres derived from the field ``<name>_voxels`` before it and the voxel size;
    no parameter (RegorConfig sets it). ``metres``: its value at the default voxel."""
    return field(default=metres, metadata={"derived": True})


@dataclass
class FeatureConfig:
    """Downsampling, normals and FPFH descriptors (open3d)."""

    voxel_size: float = param(0.05, "voxel edge for downsampling; every downsampled point is a keypoint. The "
                                    "one scale: every length set in voxels (the *_voxels parameters) is a "
                                    "multiple of it [m]", 1e-4, 100.0)
    normal_radius_voxels: float = param(2.0, "search radius for normal estimation, in voxels", 1.0, 1000.0)
    normal_radius: float = length(0.10)
    normal_max_nn: int = param(30, "max neighbours for normal estimation", 3, 1000)
    fpfh_radius_voxels: float = param(5.0, "search radius of the FPFH descriptor, in voxels", 1.0, 1000.0)
    fpfh_radius: float = length(0.25)
    fpfh_max_nn: int = param(100, "max neighbours for the FPFH descriptor", 5, 1000)
    remove_ground: bool = param(False, "drop the largest plane (a LiDAR scan's ground) before keypoints when "
                                 "both clouds are scans seen from known sensors: its rings make unrelated scans "
                                 "look aligned at the same sensor position; a cloud without viewpoint (a map) "
                                 "keeps it, and so does a scan registered against one (deviation; outdoor "
                                 "preset only)")
    min_points: int = param(30, "fewest keypoints per cloud after downsampling that are registered", 10, 100000)
    exact_search_limit: int = param(20000, "feature search is exact against clouds of up to this many keypoints "
                                     "(a scan); a larger cloud (a map) gets an "
                                     "approximate index, built once when it is prepared", 0, 100000000)
    search_probes: int = param(128, "cells of the approximate feature index scanned for a keypoint's K candidates: "
                                "more finds more of the exact candidates, slower", 1, 100000)
    search_probes_nearest: int = param(64, "cells of the approximate feature index scanned for a keypoint's nearest "
                                        "neighbour: more finds more of the exact ones, slower", 1, 100000)
    normals_toward_sensors: bool = param(True, "turn each normal toward the nearest known sensor position (a "
                                         "viewpoint, a map's trajectory) when both clouds know theirs: FPFH then "
                                         "compares a surface's seen side whatever the frames' headings (PCL's "
                                         "convention; off: open3d's solver picks the sign, as the authors run it; "
                                         "deviation)")
    range_image_resolution: float = param(1.0, "angular bin of the range image that records what a cloud's sensor saw, "
                                           "for the free-space check (coarser than the sensor's own resolution) "
                                           "[deg]", 0.05, 10.0)


@dataclass
class InitialConfig:
    """SC2-PCR++ initial stage: seeds, consensus sets, hypotheses, FS-TCD selection."""

    inlier_threshold_voxels: float = param(2.0, "residual below which a correspondence is an inlier of a "
                                                "hypothesis (tau), in voxels", 1e-3, 1000.0)
    inlier_threshold: float = length(0.10)
    compatibility_threshold_voxels: float = param(2.0, "length difference scale of pairwise compatibility (d_thre), "
                                                       "in voxels", 1e-3, 1000.0)
    compatibility_threshold: float = length(0.10)
    nms_radius_voxels: float = param(0.0, "radius of non-maximum suppression among seeds, in the source cloud, in "
                                          "voxels (authors: 2 indoor, 1 outdoor)", 0.0, 1000.0)
    nms_radius: float = length(0.0)
    seed_ratio: float = param(0.5, "fraction of correspondences used as seeds, by spectral confidence (authors: "
                                   "0.2)", 0.001, 1.0)
    k1: int = param(20, "size of the first-stage consensus set of each seed", 4, 1000)
    k2: int = param(10, "size of the second-stage consensus set of each seed", 3, 1000)
    max_correspondences: int = param(2500, "correspondences the quadratic consensus steps run on, chosen by "
                                           "initial.subset (authors: 8000 random); 0 = all", 0, 100000)
    subset: str = param("random", "which correspondences fill max_correspondences: random (authors) or best "
                         "(mutual nearest neighbours first, then by feature similarity; deviation)")
    power_iterations: int = param(10, "power iterations for leading eigenvectors", 1, 100)
    candidates: int = param(100, "feature-nearest target candidates per source point checked by FS-TCD (K)", 1, 1000)
    num_hypotheses: int = param(50, "hypotheses with the most inliers that FS-TCD compares", 1, 1000)
    ranking: str = param("candidates", "which hypotheses FS-TCD compares: the num_hypotheses with the most inliers "
                                       "in the "
                          "consensus subset (inliers, authors) or with the most source keypoints landing on one of "
                          "their K feature candidates (candidates, deviation: finds correct poses at low overlap)")
    fs_tcd_threshold_voxels: float = param(1.0, "length difference below which two verified matches agree in "
                                                "FS-TCD, in voxels", 1e-3, 1000.0)
    fs_tcd_threshold: float = length(0.05)
    refine_threshold_voxels: float = param(2.0, "inlier threshold of the post-refinement (tau_r), in voxels",
                                           1e-3, 1000.0)
    refine_threshold: float = length(0.10)
    dedupe_hypotheses: bool = param(True, "skip FS-TCD for hypotheses within 1 deg and 0.2 tau of a kept one "
                                          "(speed; deviation)")
    fs_tcd_points: int = param(2500, "random subset of source keypoints verified by FS-TCD (deviation, for large "
                                     "clouds); 0 = all", 0, 1000000)
    fs_tcd_rows: int = param(256, "rows scored for FS-TCD's max-degree (half lowest residual, half random); 0 = all "
                                  "(deviation)", 0, 100000)
    free_space_selection: bool = param(False, "FS-TCD picks the fittest hypothesis that passes the free-space "
                                        "checks (acceptance.max_free_space_violation, _both_sides), not the "
                                        "fittest of all (deviation)")
    reproduce_fs_tcd_quirk: bool = param(False, "reproduce the authors' argument overwrite in FS-TCD (refine on the "
                                                "previous hypothesis's matches)")


@dataclass
class RegenerationConfig:
    """Progressive regeneration stages, each a (neighbours, seeds) pair."""

    stage_neighbors: list[int] = param([100, 20], "k nearest neighbours forming each local region, one entry per "
                                                  "stage", 1, 1000)
    stage_seeds: list[int] = param([100, 500], "seed correspondences drawn per stage, one entry per stage", 1, 100000)
    consistency_threshold_voxels: float = param(2.0, "sigma of the centre-aware three-point consistency; pairs "
                                                     "agree within sigma/2; in voxels", 1e-3, 1000.0)
    consistency_threshold: float = length(0.10)
    gmm_k: int = param(3, "neighbours of generalized mutual matching", 1, 50)
    point_support_ratio: float = param(0.3, "a pair is kept if consistent with this fraction of its region", 0.0, 1.0)
    region_keep_ratio: float = param(0.5, "a region is dropped if it keeps less than this fraction of its "
                                          "pairs", 0.0, 1.0)
    global_threshold_voxels: float = param(2.0, "length difference threshold of the global second-order filter, "
                                                "in voxels", 1e-3, 1000.0)
    global_threshold: float = length(0.10)
    global_cap: int = param(1500, "random subset size for the global second-order filter; 0 = all "
                                  "(deviation)", 0, 100000)
    presample: int = param(0, "draw this many initial inliers with replacement before stage 1 (authors' 3DLoMatch: "
                              "100); 0 = off", 0, 100000)
    reproduce_ctc_padding_bug: bool = param(False, "count padded slots in the region keep test as the authors' code "
                                                   "does")


@dataclass
class EstimationConfig:
    """Final pose: Kabsch, then Cauchy-weighted point-level refinement over all keypoints, then
    point-to-plane refinement."""

    inlier_threshold_voxels: float = param(2.0, "nearest-neighbour distance below which a keypoint is a final "
                                                "inlier (tau_e), in voxels", 1e-3, 1000.0)
    inlier_threshold: float = length(0.10)
    max_iterations: int = param(20, "iterations of the point-level refinement", 0, 1000)
    compare_initial_pose: bool = param(True, "also refine the initial stage's pose and keep whichever ends "
                                        "with more point-level inliers (guards against regeneration drift; deviation)")
    plane_refinement: bool = param(True, "then refine point-to-plane, the threshold halved from tau_e down to "
                                    "the voxel size, so the gate judges the pose at the keypoints' resolution; "
                                    "kept when it puts at least as many keypoints within a voxel of the target "
                                    "(sparse scans' point-level poses stay decimetres off; deviation)")
    settle_rounds: int = param(0, "further rounds of refinement (point level, then planes) a pose takes until a "
                               "round moves it by less than it is known at the keypoints' resolution; where tau_e "
                               "spans several keypoint spacings a scan inside a map keeps its inlier count while "
                               "its pose still moves (deviation; outdoor preset only)", 0, 100)
    visible_candidates: int = param(8, "when the pose puts one cloud into space the other sensor saw through "
                                       "(acceptance.max_free_space_violation, _both_sides), refine up to this "
                                       "many other places the search found and take the one that does not, with "
                                       "the most inliers; the gate then judges it as any pose (0 = off; "
                                       "deviation)", 0, 100)


@dataclass
class AcceptanceConfig:
    """Quality gate: a pose that fails it is reported, never published as valid."""

    min_inliers: int = param(40, "fewest final inlier keypoints of an accepted pose", 0, 1000000)
    min_fitness: float = param(0.10, "lowest fraction of source keypoints that are final inliers", 0.0, 1.0)
    min_feature_inliers: int = param(90, "fewest initial feature matches within initial.inlier_threshold of "
                                      "the pose; geometry alone aligns planes of unrelated rooms (calibrated: "
                                      "regor-calibrate-gate). Waived for a pose its matches single out among "
                                      "every other answer measured (status: singled_out)", 0, 1000000)
    min_feature_inliers_partial: int = param(150, "the same when free space was checked from one side or none (a "
                                              "viewpoint unknown and no map view: two clouds without viewpoints, or "
                                              "too little of the scan on what the map holds): wrong poses visibility "
                                              "would reject get through on features alone (calibrated with the "
                                              "viewpoints dropped: regor-calibrate-gate)", 0, 1000000)
    min_surface_agreement: float = param(0.5, "fewest of the overlap (source keypoints within "
                                          "estimation.inlier_threshold of the target) that must lie within one "
                                          "voxel of it: a right pose puts its overlap on the target's surfaces, a "
                                          "wrong one anywhere up to the threshold, however dense the target "
                                          "(a majority rule, not fitted; 0 = off)", 0.0, 1.0)
    max_false_alarms: float = param(1.0, "most poses, among those the search tried, expected to gather the "
                                     "pose's independent feature support by chance (a-contrario; the target's "
                                     "size and the matches set the chance; 1 is the usual bound, not fitted)",
                                     1e-12, 1e12)
    max_free_space_violation: float = param(0.02, "largest fraction of one cloud's keypoints that may sit in space "
                                                  "the other "
                                             "cloud's sensor saw through, or, for a map, in front of the map's "
                                             "surfaces seen from the pose (free-space check; 1 = off; "
                                             "calibrated: regor-calibrate-gate)", 0.0, 1.0)
    max_free_space_both_sides: float = param(0.02, "largest fraction of keypoints in the other sensor's seen free "
                                                   "space that both sides may show at once: a correct pose's "
                                                   "conflicts are one sensor's artefacts (a fused fragment's other "
                                                   "views, a passer-by) and leave the other side clear, while "
                                                   "surfaces that pass through each other are seen through from "
                                                   "both (a box room's quarter turn); needs "
                                                   "both viewpoints (1 = off; calibrated: regor-calibrate-gate)",
                                             0.0, 1.0)
    free_space_margin_voxels: float = param(3.0, "a keypoint is in seen free space only when nearer than the seen "
                                                 "surface by more than this plus free_space_margin_ratio x its "
                                                 "range; in voxels", 0.0, 1000.0)
    free_space_margin: float = length(0.15)
    free_space_margin_ratio: float = param(0.02, "range-proportional part of the free-space margin (depth noise grows "
                                            "with range)", 0.0, 1.0)
    free_space_sigmas: float = param(3.0, "the free-space margin also grows by this many standard deviations of "
                                      "how well a right pose is known at the voxel size (a voxel's sigma plus a "
                                      "point's range times the turn that moves the inliers by as much); 0 = off",
                                      0.0, 10.0)
    max_opposite_sides: float = param(0.5, "largest fraction of the matched surface that the two sensors may have seen "
                                       "from opposite sides (thin objects are; a majority means the clouds are back to "
                                       "back: wrong; needs both viewpoints; 1 = off)", 0.0, 1.0)
    free_space_min_seen: int = param(50, "fewest keypoints landing on seen bins for the free-space figure to "
                                         "count", 1, 1000000)
    map_view_min_seen: float = param(0.5, "against a cloud with no viewpoint (a map), seen from the pose's sensor "
                                          "position: "
                                      "the map's side counts only when at least this fraction of the scan's keypoints "
                                      "land on bins the map fills (under a right pose the map holds the scan's "
                                      "surfaces)",
                                      0.0, 1.0)
    min_weakest_support: float = param(1.0, "fewest independent neighbourhoods of surface (one per "
                                       "features.fpfh_radius) that must face the direction the overlap's surfaces "
                                       "pin least: under one, the position along it rests on slivers of surface "
                                       "that one repeated structure (a bookshelf's bays, a row of doors) imitates, "
                                       "and the pose slid along it fits as well (a unit, not fitted; 0 = off)",
                                       0.0, 1e6)
    max_ambiguity: float = param(0.05, "withhold a pose as ambiguous when the evidence cannot tell it from a rival "
                                  "(the pose turned about the scene's symmetry: a half turn about the overlap's "
                                  "axes, a quarter turn about its surfaces' dominant direction; or one of the "
                                  "search's best three other places; refined, and moving the source by 5 tau or "
                                  "more) that would pass the visibility checks and the inlier, fitness and "
                                  "feature-match minimums on its own: when a tie between the two would give the "
                                  "pose its lead in the independent feature matches only one of them explains "
                                  "with more than this probability (a significance level, not fitted; 1 = off)",
                                  0.0, 1.0)
    reverse_check: bool = param(False, "also register target to source and accept only if that returns the inverse "
                                 "pose (within 10 deg, 3 tau); rejects rooms of other places that align (a second "
                                 "registration per accepted pose; deviation)")
    retries: int = param(0, "when the gate rejects, register a raw source again up to this many times on a "
                          "re-drawn voxel grid (the source turned by a seeded rotation) and keep the first pose "
                          "accepted at another place than the first attempt's, whose verdict stands; FPFH matches "
                          "depend strongly on the grid (recall for latency; deviation)", 0, 20)


@dataclass
class GravityConfig:
    """A ground robot's prior (core/gravity.py): the inputs' up directions, the tilt a pose may
    have between them, and the band the source sensor's height stays in. Off until both up
    directions are given."""

    source_up: str = param("unknown", "up direction in the source cloud's frame as 'x y z' (a level-mounted "
                            "LiDAR: '0 0 1'; the node can take it from an IMU), or 'unknown' (no prior)")
    target_up: str = param("unknown", "up direction in the target cloud's (the map's) frame as 'x y z', or "
                            "'unknown' (no prior)")
    max_tilt: float = param(10.0, "largest angle a pose may leave between the source's up and the target's: "
                             "the two sensors' attitude difference (a car on roads: a few deg; with an IMU's "
                             "up: its error) [deg]", 0.0, 180.0)
    height_tolerance: float = param(0.0, "how far the source's sensor may be above or below the target's "
                                     "sensor, or the map's nearest trajectory pose, beyond what max_slope "
                                     "allows over the distance between them (the same robot: its suspension "
                                     "and mounting); 0 = height not checked [m]", 0.0, 1000.0)
    max_slope: float = param(10.0, "steepest ground the robot drives on, for the height band [deg]", 0.0, 89.0)


@dataclass
class VerificationConfig:
    """Checking a pose found elsewhere (core/verification.py): how far the data may move it for it to
    count as right. The presets take the benchmarks' success tolerances."""

    max_correction: float = param(0.3, "largest translation by which the local refinement may move a given pose "
                                   "and it still be verified, the refined pose's own uncertainty at the keypoints' "
                                   "resolution included (the correction is reported either way) [m]", 0.0, 1e6)
    max_correction_deg: float = param(15.0, "largest turn by which the local refinement may move a given pose and "
                                       "it still be verified [deg]", 0.0, 180.0)


def parse_up(text: str):
    """The unit up vector written as 'x y z' (or 'x, y, z'), or None for 'unknown'."""
    if text.strip().lower() == "unknown":
        return None
    up = parse_numbers(text, 3, "up direction", "three numbers 'x y z' (not all zero) or 'unknown'")
    if np.linalg.norm(up) < 1e-9:
        raise ConfigError(f"up direction {text!r}: give three numbers 'x y z' (not all zero) or 'unknown'")
    return up / np.linalg.norm(up)


PRESETS = ("indoor", "outdoor", "object")
# string parameters and the values they accept
CHOICES = {"initial.subset": ("random", "best"), "initial.ranking": ("inliers", "candidates")}


@dataclass
class RegorConfig:
    """The whole configuration; ``RegorConfig.preset(name)`` gives a named starting point."""

    features: FeatureConfig = field(default_factory=FeatureConfig)
    initial: InitialConfig = field(default_factory=InitialConfig)
    regeneration: RegenerationConfig = field(default_factory=RegenerationConfig)
    estimation: EstimationConfig = field(default_factory=EstimationConfig)
    acceptance: AcceptanceConfig = field(default_factory=AcceptanceConfig)
    gravity: GravityConfig = field(default_factory=GravityConfig)
    verification: VerificationConfig = field(default_factory=VerificationConfig)
    seed: int = param(51, "seed of the random generator; the same seed gives the same pose", 0, 2**31 - 1)

    def __post_init__(self):
        self.derive_lengths()

    def derive_lengths(self) -> RegorConfig:
        """Set every length in metres from its multiple of the voxel (the module's docstring)."""
        voxel = self.features.voxel_size
        for section in _sections(self).values():
            for f in dataclasses.fields(section):
                if f.metadata.get("derived"):
                    setattr(section, f.name, round(getattr(section, f.name + "_voxels") * voxel, LENGTH_DIGITS))
        return self

    @classmethod
    def preset(cls, name: str) -> RegorConfig:
        """indoor: the paper's 3DMatch settings; outdoor: its KITTI settings; object: indoor scaled
        to table-top objects (about 0.1-0.5 m across). Deviations from the authors are marked in
        the field descriptions."""
        if name == "indoor":
            return cls()
        if name == "outdoor":
            # the paper's KITTI settings: wider normals and thresholds, but the length tests of
            # matches (compatibility, FS-TCD, consistency, the global filter) kept at 0.1 m
            return cls(
                features=FeatureConfig(voxel_size=0.30, normal_radius_voxels=3.0,
                                       remove_ground=True, normals_toward_sensors=True),
                initial=InitialConfig(compatibility_threshold_voxels=1 / 3, k1=40, k2=30,
                                      fs_tcd_threshold_voxels=1 / 3, refine_threshold_voxels=4.0, subset="best"),
                regeneration=RegenerationConfig(consistency_threshold_voxels=1 / 3, global_threshold_voxels=1 / 3),
                estimation=EstimationConfig(inlier_threshold_voxels=4.0, settle_rounds=3, visible_candidates=8),
                acceptance=AcceptanceConfig(min_feature_inliers=5, min_feature_inliers_partial=60,
                                            max_free_space_violation=0.03),
                verification=VerificationConfig(max_correction=0.6, max_correction_deg=5.0),
            )
        if name == "object":
            s = 0.06  # object scale relative to indoor: the indoor voxel, so every length, scaled
            return cls(
                features=FeatureConfig(voxel_size=0.05 * s, normals_toward_sensors=False),
                estimation=EstimationConfig(visible_candidates=0),
                acceptance=AcceptanceConfig(min_feature_inliers=50, min_feature_inliers_partial=95,
                                            max_free_space_violation=0.06),
                verification=VerificationConfig(max_correction=0.3 * s),
            )
        raise ConfigError(f"unknown preset {name!r}; choose one of {', '.join(PRESETS)}")

    # --- flat view: "section.field" names, used by ROS parameters, the CLI and YAML files ---

    def parameters(self) -> Iterator[tuple[str, Any, dataclasses.Field]]:
        """Yield (dotted name, current value, dataclass field) for every leaf that is set (the
        lengths in metres are derived: ``lengths``)."""
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if dataclasses.is_dataclass(value):
                for sub in dataclasses.fields(value):
                    if not sub.metadata.get("derived"):
                        yield f"{f.name}.{sub.name}", getattr(value, sub.name), sub
            else:
                yield f.name, value, f

    def lengths(self) -> dict[str, float]:
        """Every derived length in metres by its dotted name (``features.normal_radius``)."""
        return {f"{name}.{f.name}": getattr(section, f.name) for name, section in _sections(self).items()
                for f in dataclasses.fields(section) if f.metadata.get("derived")}

    def to_flat(self) -> dict[str, Any]:
        """Every setting by its dotted name (the ROS parameters' names)."""
        return {name: value for name, value, _ in self.parameters()}

    def replace(self, overrides: dict[str, Any]) -> RegorConfig:
        """A validated copy with ``{"section.field" or unique "field": value}`` applied. A length
        given in metres by its derived name (``features.normal_radius``) sets its multiple of the
        voxel, at the voxel the copy ends with."""
        flat, lengths = self.to_flat(), self.lengths()
        in_metres = {}
        for key, value in overrides.items():
            name = resolve_name(key, {**flat, **lengths})
            if name in lengths:
                in_metres[name] = coerce(name, value, lengths[name])
            else:
                flat[name] = coerce(name, value, flat[name])
        for name, metres in in_metres.items():
            flat[name + "_voxels"] = metres / flat["features.voxel_size"]
        new = RegorConfig()
        for name, value in flat.items():
            section, _, leaf = name.rpartition(".")
            setattr(getattr(new, section) if section else new, leaf, value)
        new.derive_lengths().validate()
        return new

    def validate(self) -> RegorConfig:
        """Raise ConfigError naming the first field that is out of range or inconsistent."""
        for name, value, f in self.parameters():
            if name in CHOICES and value not in CHOICES[name]:
                raise ConfigError(f"{name}={value!r}: choose one of {', '.join(CHOICES[name])}")
            low, high = f.metadata["range"]
            values = value if isinstance(value, list) else [value]
            for v in values:
                if isinstance(v, bool):
                    continue
                if low is not None and v < low or high is not None and v > high:
                    raise ConfigError(f"{name}={value!r} is outside its valid range [{low}, {high}]")
        regen = self.regeneration
        if len(regen.stage_neighbors) != len(regen.stage_seeds):
            raise ConfigError("regeneration.stage_neighbors and regeneration.stage_seeds must have "
                              f"one entry per stage (got {len(regen.stage_neighbors)} and {len(regen.stage_seeds)})")
        if self.initial.k2 > self.initial.k1:
            raise ConfigError(f"initial.k2={self.initial.k2} must not exceed initial.k1={self.initial.k1}")
        acceptance = self.acceptance
        if acceptance.min_feature_inliers_partial < acceptance.min_feature_inliers:
            raise ConfigError(f"acceptance.min_feature_inliers_partial={acceptance.min_feature_inliers_partial} must "
                              f"not be below acceptance.min_feature_inliers={acceptance.min_feature_inliers} (a check "
                              "that sees less needs more feature support)")
        for name in ("source_up", "target_up"):
            try:
                parse_up(getattr(self.gravity, name))
            except ConfigError as error:
                raise ConfigError(f"gravity.{name}: {error}") from None
        return self


def _sections(config: RegorConfig) -> dict[str, Any]:
    """Each section of ``config`` by its name."""
    return {f.name: getattr(config, f.name) for f in dataclasses.fields(config)
            if dataclasses.is_dataclass(getattr(config, f.name))}


def resolve_name(key: str, flat: dict[str, Any]) -> str:
    """Accept a dotted name or a leaf name that is unique across sections."""
    if key in flat:
        return key
    matches = [name for name in flat if name.rpartition(".")[2] == key]
    if len(matches) == 1:
        return matches[0]
    if matches:
        raise ConfigError(f"parameter {key!r} is ambiguous: use one of {', '.join(matches)}")
    raise ConfigError(f"unknown parameter {key!r}")


def coerce(name: str, value: Any, current: Any) -> Any:
    """Convert a value (possibly a string from a command line) to the type of the current one;
    ConfigError naming ``name`` when it is not one."""
    try:
        if isinstance(current, str):
            return str(value)
        if isinstance(current, bool):
            if isinstance(value, str):
                if value.lower() in ("1", "true", "yes", "on"):
                    return True
                if value.lower() in ("0", "false", "no", "off"):
                    return False
                raise ValueError(value)
            return bool(value)
        if isinstance(current, list):
            if isinstance(value, str):
                value = [v for v in value.replace("[", "").replace("]", "").split(",") if v.strip()]
            return [int(v) for v in value]
        if isinstance(current, int):
            as_float = float(value)
            if as_float != int(as_float):
                raise ValueError(value)
            return int(as_float)
        return float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{name}: cannot use {value!r} as a {type(current).__name__}") from None
