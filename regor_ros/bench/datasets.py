"""The shared data sets as the benchmarks read them: pair folders, map sequences with their
queries and odometry, the 3DMatch lists, and the query inputs made from them (a narrow view, a
thinned scan, a shaken history, a tiled map). lab/ scripts and tests load data through here.
"""
from __future__ import annotations

import dataclasses
import json
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..core import ORIGIN, RegorConfig, ScanSequence, random_rigid_motion, to_matrix
from ..io.map_file import read_trajectory
from .results import selected

UP_Z = np.array([0.0, 0.0, 1.0])  # a level-mounted sensor's up in its own frame
MAP_UP = np.array([0.0, 0.0, 1.0])   # the shared maps' up: each is built gravity-aligned, z up
INPUTS = ("single", "sequence")
STRESS_INPUTS = ("single", "thinned", "sequence")
THINNING = 4  # --stress: every 4th point of a scan, a sparse sensor's density (64 beams -> 16)
SHAKE_SHIFT = 0.03  # [m] a shaken scan's odometry shift (standard deviation per axis)
TILE_SPACING = 400.0  # metres between copies: beyond a LiDAR's reach
# --narrow: each query scan as a narrow solid-state sensor at its origin would see it, facing four
# ways about its z axis: the nearest return in each NARROW_STEP_DEG bin over NARROW_FIELD_DEG square,
# about a Livox Avia's field and the returns of the Avia maps' decimated scans (bins finer than a
# degree: the Avia's pattern returns several points within one); a view with fewer than
# NARROW_MIN_RETURNS faces the sky or the scanner's blind side and is no query. The xseason winter
# scans seen so are sparse scans from another recording than their map's (the summer's).
NARROW_FIELD_DEG = 70.0
NARROW_STEP_DEG = 0.7
NARROW_HEADINGS = (0, 90, 180, 270)
NARROW_INPUTS = tuple(f"narrow {heading:03d}" for heading in NARROW_HEADINGS)
NARROW_MIN_RETURNS = 500
# --at-rest: a narrow sensor at rest returns RESTING_FRAMES frames (the node's accumulate_scans in map
# mode), each the nearest return per bin of a grid shifted by a random fraction of a bin: a
# non-repeating pattern fills in the field of view frame by frame (input `narrow <heading> at rest`)
RESTING_FRAMES = 5
AT_REST = " at rest"
NARROW_AT_REST_INPUTS = tuple(f"{narrow}{AT_REST}" for narrow in NARROW_INPUTS)
SAMPLE_SEED = 600                # fixes --sample's draw
SHORT_NAMES = {  # scene folder -> the place name the other indoor sets use (bench_results.place)
    "7-scenes-redkitchen": "redkitchen", "sun3d-home_at-home_at_scan1_2013_jan_1": "home_at",
    "sun3d-hotel_uc-scan3": "hotel_uc", "sun3d-hotel_umd-maryland_hotel3": "hotel_umd3",
    "sun3d-mit_76_studyroom-76-1studyroom2": "studyroom", "sun3d-home_md-home_md_scan9_2012_sep_30": "home_md",
    "sun3d-mit_lab_hj-lab_hj_tea_nov_2_2012_scan1_erika": "lab_hj",
}


def load_pairs(folder: Path, name_filter: str | None):
    """Each selected pair; its index in pairs.json seeds the pair's random motion, so a filtered
    run moves a pair as a full run does."""
    listing = json.loads((folder / "pairs.json").read_text())
    for index, entry in enumerate(listing):
        if not selected(entry["name"], name_filter):
            continue
        d = folder / entry["name"]
        yield Pair(index, entry["name"], entry["kind"], np.load(d / "src.npy"), np.load(d / "tgt.npy"),
                   np.loadtxt(d / "gt.txt"), _viewpoint(entry.get("src_viewpoint", ORIGIN)),
                   _viewpoint(entry.get("tgt_viewpoint", ORIGIN)))


def _viewpoint(value):
    return None if value is None else np.asarray(value, dtype=np.float64)


@dataclass
class Pair:
    index: int
    name: str
    kind: str
    src: np.ndarray
    tgt: np.ndarray
    T_gt: np.ndarray | None              # T_target_source; None: different places, no true pose
    src_viewpoint: np.ndarray | None     # sensor position in the cloud's frame; None = unknown
    tgt_viewpoint: np.ndarray | None
    src_up: np.ndarray | None = None     # up direction in the cloud's frame; None = unknown
    tgt_up: np.ndarray | None = None

    def moved(self, seed: int | None) -> Pair:
        """The pair with its source (and the source's viewpoint and up) moved by the seeded motion."""
        if seed is None:
            return self
        M = random_rigid_motion([seed, self.index])
        viewpoint = None if self.src_viewpoint is None else M[:3, :3] @ self.src_viewpoint + M[:3, 3]
        return dataclasses.replace(self, src=self.src @ M[:3, :3].T + M[:3, 3],
                                   T_gt=None if self.T_gt is None else self.T_gt @ np.linalg.inv(M),
                                   src_viewpoint=viewpoint,
                                   src_up=None if self.src_up is None else M[:3, :3] @ self.src_up)

    def unseen(self) -> Pair:
        """The pair with neither sensor position known (--no-viewpoints: a map without its
        trajectory, clouds not in their sensors' frames): no free space is checked and the normals
        keep the solver's signs."""
        return dataclasses.replace(self, src_viewpoint=None, tgt_viewpoint=None)

    def swapped(self) -> Pair:
        """The target as the source and the source as the target; no true pose."""
        return dataclasses.replace(self, src=self.tgt, tgt=self.src, T_gt=None,
                                   src_viewpoint=self.tgt_viewpoint, tgt_viewpoint=self.src_viewpoint,
                                   src_up=self.tgt_up, tgt_up=self.src_up)

    def configured(self, config: RegorConfig) -> RegorConfig:
        """``config`` with the pair's up directions as its gravity prior, when both are known."""
        if self.src_up is None or self.tgt_up is None:
            return config
        return config.replace(gravity_overrides(self.src_up, self.tgt_up))


def gravity_overrides(source_up: np.ndarray, target_up: np.ndarray) -> dict[str, str]:
    """The settings that give the gravity prior these up directions (each in its cloud's frame)."""
    return {"gravity.source_up": " ".join(f"{v:.9f}" for v in source_up),
            "gravity.target_up": " ".join(f"{v:.9f}" for v in target_up)}


def load_poses(path: Path) -> dict[int, np.ndarray]:
    """A TUM file whose first column numbers the scans, as {scan number: 4x4}."""
    stamps, poses = read_trajectory(path)
    return {int(k): T for k, T in zip(stamps, poses, strict=True)}


@dataclass
class Query:
    sequence: str
    id: str
    kind: str                 # scan, or submap (scans merged around one)
    scan: np.ndarray
    truth: np.ndarray         # T_map_scan
    history: ScanSequence | None  # the scans received up to it with odometry; None for a submap

    def cloud(self, which: str):
        """The input ``which`` (INPUTS, STRESS_INPUTS, NARROW_INPUTS, NARROW_AT_REST_INPUTS: a list
        of frames) of this query; None when it has none."""
        if which.endswith(AT_REST):
            frames = resting_frames(self.scan, float(which.split()[1]), f"{self.sequence}/{self.id}/{which}")
            return frames if len(frames) == RESTING_FRAMES else None
        if which.startswith("narrow"):
            view = narrow_view(self.scan, float(which.split()[1]))
            return view if len(view) >= NARROW_MIN_RETURNS else None
        return {"single": self.scan, "thinned": self.scan[::THINNING], "sequence": self.history}[which]


def narrow_view(scan: np.ndarray, heading_deg: float, shift: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """The points of ``scan`` (in its sensor's frame) a narrow sensor at the origin facing ``heading_deg``
    about z would return: the nearest in each NARROW_STEP_DEG bin of azimuth and elevation within
    NARROW_FIELD_DEG of the heading, in the order a scanning sensor returns them (column by column).
    ``shift``: the bins' offset in azimuth and elevation, in bins."""
    half = NARROW_FIELD_DEG / 2
    distance = np.linalg.norm(scan, axis=1)
    azimuth = (np.degrees(np.arctan2(scan[:, 1], scan[:, 0])) - heading_deg + 180.0) % 360.0 - 180.0
    elevation = np.degrees(np.arcsin(np.clip(scan[:, 2] / np.maximum(distance, 1e-9), -1.0, 1.0)))
    inside = np.flatnonzero((np.abs(azimuth) < half) & (np.abs(elevation) < half) & (distance > 0))
    columns = int(np.ceil(NARROW_FIELD_DEG / NARROW_STEP_DEG)) + 1
    bins = (np.floor((azimuth[inside] + half) / NARROW_STEP_DEG + shift[0]).astype(np.int64) * columns
            + np.floor((elevation[inside] + half) / NARROW_STEP_DEG + shift[1]).astype(np.int64))
    order = np.lexsort((distance[inside], bins))
    first = np.r_[True, bins[order][1:] != bins[order][:-1]][:len(order)]
    return scan[inside[order[first]]]


def consecutive_scans(queries: list[Query]) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """(older scan, newer scan, the odometry's translation between them) of every pair of
    consecutive scans the queries' histories hold, each pair once (the histories overlap)."""
    pairs = {}
    for query in queries:
        history = query.history
        if history is None:
            continue
        for a, b, pose_a, pose_b in zip(history.scans[:-1], history.scans[1:], history.poses[:-1],
                                        history.poses[1:], strict=True):
            pairs[(pose_a.tobytes(), pose_b.tobytes())] = (a, b, float(np.linalg.norm(pose_b[:3, 3] - pose_a[:3, 3])))
    return list(pairs.values())


def resting_frames(scan: np.ndarray, heading_deg: float, name: str) -> list[np.ndarray]:
    """The frames a narrow sensor at rest facing ``heading_deg`` returns of ``scan``: RESTING_FRAMES
    narrow views, the first on the grid, each later one's grid shifted by a random fraction of a bin
    (seeded by ``name``), oldest first; those with fewer than NARROW_MIN_RETURNS left out."""
    shifts = np.random.default_rng(zlib.crc32(name.encode())).uniform(0.0, 1.0, (RESTING_FRAMES, 2))
    shifts[-1] = 0.0   # the newest frame, whose pose is registered, is the narrow view itself
    views = [narrow_view(scan, heading_deg, (float(a), float(e))) for a, e in shifts]
    return [view for view in views if len(view) >= NARROW_MIN_RETURNS]


def sequence_folders(folders: list[Path]) -> list[Path]:
    """The sequence folders (each with queries.json) in each of ``folders``, in name order."""
    return sorted((p for folder in folders for p in folder.iterdir() if (p / "queries.json").is_file()),
                  key=lambda p: p.name)


def load_sequence(folder: Path):
    """(map points, map trajectory (K, 4, 4) or None, [Query]) of one sequence folder."""
    queries = json.loads((folder / "queries.json").read_text())
    trajectory_file, odometry_file = folder / "map_trajectory.txt", folder / "odometry.txt"
    trajectory = np.array(list(load_poses(trajectory_file).values())) if trajectory_file.is_file() else None
    odometry = load_poses(odometry_file) if odometry_file.is_file() else {}
    out = []
    for q in queries:
        history = None
        if q["kind"] == "scan" and q.get("sequence") and all(k in odometry for k in q["sequence"]):
            history = ScanSequence([np.load(folder / "scans" / f"{k:06d}.npy") for k in q["sequence"]],
                                   [odometry[k] for k in q["sequence"]])
        out.append(Query(folder.name, q["id"], q["kind"], np.load(folder / "queries" / q["id"] / "scan.npy"),
                         np.loadtxt(folder / "queries" / q["id"] / "gt.txt"), history))
    return np.load(folder / "map.npy"), trajectory, out


def place_of(sequence: str) -> str:
    """The place a sequence was recorded, for leave-one-place-out calibration: its name without
    the SLAM system that built the map (``fastlio_avia_hku2`` is ``avia_hku2``, the campus of the
    pair sets' ``avia_hku*``)."""
    return sequence.split("_", 1)[1]


def one_place(a: str, b: str) -> bool:
    """Whether two sequences were recorded at one place: one's place is in the other's name
    (``fastlio_avia_hku2`` and ``avia_hku2_loop``: one walk, one frame). A query of one against the
    other's map has a true pose there, so it is no cross-map query."""
    return place_of(a) in b or place_of(b) in a


def imu_up(truth: np.ndarray, map_up: np.ndarray, degrees: float, name: str) -> np.ndarray:
    """The up an IMU would give in the frame of a scan whose true pose in the map is ``truth``:
    the map's up carried into the scan's frame, tilted by ``degrees`` about a horizontal axis drawn
    at random (seeded by the query's ``name``, so every run and method gives a query the same up)."""
    up = truth[:3, :3].T @ map_up
    rng = np.random.default_rng(zlib.crc32(name.encode()))
    axis = np.cross(up, rng.normal(size=3))
    turn = Rotation.from_rotvec(np.radians(degrees) * axis / np.linalg.norm(axis)).as_matrix()
    return turn @ up


def shaken(sequence: ScanSequence, degrees: float, rng: np.random.Generator) -> ScanSequence:
    """The sequence with each older scan's odometry turned by ``degrees`` about a random axis
    through its sensor and shifted by a few centimetres: a hand-held sensor's deskew and odometry
    error, which no shared recording has (core/shake.py)."""
    poses = []
    for pose in sequence.poses[:-1]:
        axis = rng.normal(size=3)
        turn = Rotation.from_rotvec(np.radians(degrees) * axis / np.linalg.norm(axis)).as_matrix()
        poses.append(pose @ to_matrix(turn, rng.normal(0.0, SHAKE_SHIFT, 3)))
    return ScanSequence(sequence.scans, poses + [sequence.poses[-1]], sequence.viewpoint)


def tile_poses(tiles: int) -> list[np.ndarray]:
    """Where each of ``tiles`` copies of a map goes: on a grid, each turned about the vertical."""
    side = int(np.ceil(np.sqrt(tiles)))
    poses = []
    for i in range(tiles):
        c, s = np.cos(0.7 * i), np.sin(0.7 * i)
        poses.append(to_matrix(np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]),
                               np.array([TILE_SPACING * (i % side), TILE_SPACING * (i // side), 0.0])))
    return poses


def tiled(cloud: np.ndarray, tiles: int) -> tuple:
    """``tiles`` copies of the map placed by tile_poses, and their poses."""
    poses = tile_poses(tiles)
    return np.vstack([cloud @ pose[:3, :3].T + pose[:3, 3] for pose in poses]), poses


def pair_name(entry: dict) -> str:
    """``3dmatch_<place>_<source>_<target>``, as the other indoor sets name their pairs."""
    scene = SHORT_NAMES.get(entry["scene"], entry["scene"].replace("_", "-"))
    return f"3dmatch_{scene}_{entry['j']}_{entry['i']}"


def load_list(folder: Path, sample: int | None, name_filter: str | None) -> list[dict]:
    """The entries of ``pairs.json`` selected by ``--pairs`` (names) and ``--sample`` (a seeded draw,
    in list order), each with its pair name."""
    entries = json.loads((folder / "pairs.json").read_text())
    for index, entry in enumerate(entries):
        missing = {"bench", "scene", "i", "j", "T"} - set(entry)
        if missing:
            raise ValueError(f"{folder / 'pairs.json'}: entry {index} lacks {', '.join(sorted(missing))}")
        entry["index"], entry["name"] = index, pair_name(entry)
    entries = [e for e in entries if selected(e["name"], name_filter)]
    if sample is not None and sample < len(entries):
        rng = np.random.default_rng(SAMPLE_SEED)
        entries = [entries[i] for i in np.sort(rng.choice(len(entries), sample, replace=False))]
    return entries


class Fragments:
    """Fragments loaded once each (a fragment is in many pairs)."""

    def __init__(self, folder: Path):
        self.folder = folder
        self.loaded: dict = {}

    def __call__(self, scene: str, k: int) -> np.ndarray:
        key = (scene, k)
        if key not in self.loaded:
            path = self.folder / scene / f"{k}.npy"
            if not path.is_file():
                raise FileNotFoundError(f"{path}: fragment {k} of {scene} is listed in pairs.json but missing")
            self.loaded[key] = np.load(path)
        return self.loaded[key]


def as_pair(entry: dict, fragments: Fragments) -> Pair:
    return Pair(entry["index"], entry["name"], "indoor", fragments(entry["scene"], entry["j"]),
                fragments(entry["scene"], entry["i"]), np.asarray(entry["T"], dtype=np.float64),
                np.asarray(ORIGIN), np.asarray(ORIGIN))
