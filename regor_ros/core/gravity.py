"""A ground robot's prior: its scan and its map share "up", and its sensor stays near the ground.

A level-mounted sensor (or an IMU's roll and pitch) gives the up direction in the scan's frame;
a map built by a gravity-aware SLAM has it too. A pose may then tilt the scan's up away from the
map's by at most ``max_tilt``; every other orientation (tipped over, a sensor up in a wall) is
impossible and never competes with the right one. Where it pays:

- consistency: two correct correspondences keep their height difference along up, within the
  length threshold plus what the tilt allows over their distance (the search becomes 4-DoF in
  spirit, as Quatro's and hdl_global_localization's are);
- estimation: every rotation (hypotheses, refinements) is brought inside the tilt cone;
- the gate (core/gate/, with the reason): a pose outside the cone, or held on its edge (the up
  given is off by more than the cone allows), or whose sensor height leaves the band, is
  rejected, and a symmetric rival that turns the scan over is not a rival.

The height band is relative to where the target was seen from (its sensor, or the map's
trajectory, which is the same robot's sensor height above its own floor): the source's sensor
may differ in height by ``height_tolerance`` plus what the ground's slope (``max_slope``)
allows over the horizontal distance between them. A scan never sees the floor under its own
sensor (the beams' blind circle), so the trajectory, not a floor fit, is the reference.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .cloud import PreparedCloud
from .config import GravityConfig, parse_up

EDGE_ROUNDING_DEG = 1e-6  # a rotation clamped onto the tilt cone's edge lands there up to rounding
# a pose held on the edge: clamped, then refined, it stays within some 1e-6 deg of it; a pose the data
# puts inside lands this near the edge about once in max_tilt / EDGE_HELD_DEG poses
EDGE_HELD_DEG = 1e-3


@dataclass(frozen=True)
class GravityPrior:
    """Which way is up in each cloud, and how far a pose may tilt or lift the source's sensor."""

    source_up: np.ndarray     # (3,) unit, in the source frame
    target_up: np.ndarray     # (3,) unit, in the target frame
    max_tilt_deg: float
    height_tolerance: float   # metres; 0: the height is not checked
    max_slope_deg: float

    @classmethod
    def of(cls, config: GravityConfig) -> GravityPrior | None:
        """The prior the configuration states, or None when either up direction is unknown."""
        source_up, target_up = parse_up(config.source_up), parse_up(config.target_up)
        if source_up is None or target_up is None:
            return None
        return cls(source_up, target_up, config.max_tilt, config.height_tolerance, config.max_slope)

    def turned(self, rotation: np.ndarray) -> GravityPrior:
        """The prior for the source turned by ``rotation`` (3x3)."""
        return replace(self, source_up=rotation @ self.source_up)

    def swapped(self) -> GravityPrior:
        """The prior for registering the target to the source."""
        return replace(self, source_up=self.target_up, target_up=self.source_up)

    def tilt_deg(self, rotations: np.ndarray) -> np.ndarray:
        """Angle between the source's up turned by each (..., 3, 3) rotation and the target's up."""
        cosine = np.einsum("...ij,j,i->...", rotations, self.source_up, self.target_up)
        return np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))

    def clamp(self, rotations: np.ndarray) -> np.ndarray:
        """Each (..., 3, 3) rotation, turned by the smallest rotation that brings its tilt within
        max_tilt (about the axis perpendicular to both ups); rotations inside are unchanged."""
        turned_up = rotations @ self.source_up                                      # (..., 3)
        axis = np.cross(turned_up, self.target_up)
        sine = np.linalg.norm(axis, axis=-1)
        tilt = np.arctan2(sine, turned_up @ self.target_up)
        excess = tilt - np.radians(self.max_tilt_deg)
        fix = excess > 0
        if not np.any(fix):
            return rotations
        # upside down exactly: any horizontal axis will do
        fallback = np.cross(self.target_up, _any_perpendicular(self.target_up))
        axis = np.where((sine > 1e-12)[..., None], axis / np.maximum(sine, 1e-12)[..., None], fallback)
        correction = _axis_angle(axis, np.where(fix, excess, 0.0))
        return correction @ rotations

    def height_offsets(self, source: np.ndarray, target: np.ndarray):
        """The compatibility condition for consistency.compatibility: (each correspondence's
        height offset along up, the slack per metre): two correct correspondences' offsets agree
        within the length threshold plus the tilt's share of their distance."""
        return source @ self.source_up - target @ self.target_up, float(np.sin(np.radians(self.max_tilt_deg)))

    def allows(self, transforms: np.ndarray, source: PreparedCloud, target: PreparedCloud) -> np.ndarray:
        """(S,) bool: which of the (S, 4, 4) poses stay inside the tilt cone and keep the source's
        sensor in the height band (when the height is checked): the prior's one predicate, which
        the search's filter and the gate's reason both ask."""
        inside = self.tilt_inside(transforms[:, :3, :3])
        band = self.height_band(transforms, source, target)
        return inside if band is None else inside & inside_band(band)

    def tilt_inside(self, rotations: np.ndarray) -> np.ndarray:
        """Whether each (..., 3, 3) rotation's tilt is within max_tilt; a rotation clamped onto
        the cone's edge is inside, up to rounding."""
        return self.tilt_deg(rotations) <= self.max_tilt_deg + EDGE_ROUNDING_DEG

    def held_at_edge(self, rotations: np.ndarray) -> np.ndarray:
        """Whether each (..., 3, 3) rotation lies on the cone's edge, where clamp put it: the data
        pulled the pose further than max_tilt from the up given, so that up is off by more than
        max_tilt allows (an IMU read while turning or accelerating, a map whose z is not up) and the
        pose is where the prior held it, not where the scan fits (EDGE_HELD_DEG)."""
        return np.abs(self.tilt_deg(rotations) - self.max_tilt_deg) <= EDGE_HELD_DEG

    def height_band(self, transforms: np.ndarray, source: PreparedCloud, target: PreparedCloud):
        """For (S, 4, 4) poses: the height of the source's sensor above the target viewpoint
        horizontally nearest to it (along up), the height allowed there and their horizontal
        distance, each (S,); None when not checked: no height band, the source's sensor unknown
        (its newest viewpoint is used: a fused sequence's pose is its newest scan's) or nowhere
        the target was seen from."""
        if self.height_tolerance <= 0 or not source.views or source.viewpoints is None:
            return None
        seen_from = target.viewpoints
        if seen_from is None and target.map_view is not None and len(target.map_view.trajectory):
            seen_from = target.map_view.trajectory
        if seen_from is None:
            return None
        sensors = transforms[:, :3, :3] @ source.viewpoints[-1] + transforms[:, :3, 3]   # (S, 3)
        offset = sensors[:, None] - seen_from[None]                                      # (S, K, 3)
        height = offset @ self.target_up
        horizontal = np.linalg.norm(offset - height[..., None] * self.target_up, axis=-1)
        nearest = np.argmin(horizontal, axis=1)[:, None]
        height = np.take_along_axis(height, nearest, axis=1)[:, 0]
        distance = np.take_along_axis(horizontal, nearest, axis=1)[:, 0]
        allowed = self.height_tolerance + distance * np.tan(np.radians(self.max_slope_deg))
        return height, allowed, distance


def inside_band(band) -> np.ndarray:
    """Whether each pose of a height_band keeps the source's sensor within the height allowed."""
    height, allowed, _ = band
    return np.abs(height) <= allowed


def _any_perpendicular(v: np.ndarray) -> np.ndarray:
    other = np.eye(3)[int(np.argmin(np.abs(v)))]
    p = np.cross(v, other)
    return p / np.linalg.norm(p)


def _axis_angle(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rodrigues' rotation matrices of (..., 3) unit axes and (...) angles."""
    k = np.zeros(axis.shape[:-1] + (3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -axis[..., 2], axis[..., 1], -axis[..., 0]
    k = k - np.swapaxes(k, -1, -2)
    s, c = np.sin(angle)[..., None, None], np.cos(angle)[..., None, None]
    return np.eye(3) + s * k + (1 - c) * (k @ k)


def clamp_of(prior: GravityPrior | None):
    """The prior's clamp of rotations into its tilt cone, or None without a prior (the
    refinements' ``clamp``)."""
    return None if prior is None else prior.clamp
