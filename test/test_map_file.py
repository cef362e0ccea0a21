"""A map from files: cloud and TUM trajectory read, the prepared map cached, reused and rebuilt."""
from pathlib import Path

import numpy as np
import open3d as o3d
import pytest
from conftest import DATA, load_map_query

from regor_ros.core import RegorConfig, register
from regor_ros.core.metrics import is_success
from regor_ros.io.cloud_io import CloudFileError
from regor_ros.io.map_file import load_map_file, read_trajectory

SEQUENCE = "fastlio_avia_hku2"


@pytest.fixture(scope="module")
def map_files(tmp_path_factory):
    """The real Avia map as a binary PCD and its trajectory in TUM format, in a fresh folder."""
    scan, cloud, truth = load_map_query(SEQUENCE, "scan_000005")
    folder = tmp_path_factory.mktemp("map")
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud))
    assert o3d.io.write_point_cloud(str(folder / "map.pcd"), pcd, write_ascii=False)
    (folder / "trajectory.txt").write_text((DATA / "maps" / SEQUENCE / "map_trajectory.txt").read_text())
    return folder / "map.pcd", folder / "trajectory.txt", scan, truth


def test_tum_trajectory_is_read_and_bad_files_say_why(tmp_path, map_files):
    stamps, poses = read_trajectory(map_files[1])
    assert poses.shape == (len(stamps), 4, 4) and len(stamps) > 10
    np.testing.assert_allclose(poses[:, :3, :3] @ poses[:, :3, :3].transpose(0, 2, 1),
                               np.tile(np.eye(3), (len(poses), 1, 1)), atol=1e-9)
    bad = tmp_path / "bad.txt"
    bad.write_text("0 1 2 3 0 0 0\n")
    with pytest.raises(CloudFileError, match="8 numbers"):
        read_trajectory(bad)
    bad.write_text("0 1 2 3 0 0 0 0\n")
    with pytest.raises(CloudFileError, match="zero quaternion"):
        read_trajectory(bad)


def test_the_prepared_map_is_cached_once_for_each_key_and_rebuilt_when_unreadable(map_files, tmp_path):
    """The cache lives in the cache folder, never beside the user's map: one file for each map,
    trajectory and feature settings, so switching between them rewrites none."""
    map_file, trajectory_file, scan, truth = map_files
    config = RegorConfig.preset("outdoor")
    warnings = []
    cache_dir = tmp_path / "cache"
    first = load_map_file(map_file, config, trajectory_file, cache_dir=cache_dir, warn=warnings.append)
    assert first.info["map_cache"] == "built" and not warnings
    assert Path(first.info["map_cache_file"]).parent == cache_dir
    assert not list(map_file.parent.glob("*.regor-cache.npz"))
    second = load_map_file(map_file, config, trajectory_file, cache_dir=cache_dir, warn=warnings.append)
    assert second.info["map_cache"] == "loaded" and not warnings
    fresh, cached = register(scan, first.prepared, config), register(scan, second.prepared, config)
    assert fresh.accepted and is_success(fresh.transform, truth, "outdoor")
    np.testing.assert_array_equal(cached.transform, fresh.transform)
    assert cached.summary().visibility == fresh.summary().visibility
    assert len(second.prepared.map_view.trajectory) == len(first.prepared.map_view.trajectory) > 0

    # other feature settings, or no trajectory: a cache of their own, the first one kept
    coarser = config.replace({"features.voxel_size": 0.4})
    other = load_map_file(map_file, coarser, trajectory_file, cache_dir=cache_dir, warn=warnings.append)
    alone = load_map_file(map_file, coarser, None, cache_dir=cache_dir, warn=warnings.append)
    assert other.info["map_cache"] == alone.info["map_cache"] == "built" and not warnings
    assert len({first.info["map_cache_file"], other.info["map_cache_file"], alone.info["map_cache_file"]}) == 3
    again = load_map_file(map_file, config, trajectory_file, cache_dir=cache_dir, warn=warnings.append)
    assert again.info["map_cache"] == "loaded"
    # a truncated file: unreadable, rebuilt
    cache = Path(other.info["map_cache_file"])
    cache.write_bytes(cache.read_bytes()[:1000])
    assert load_map_file(map_file, coarser, trajectory_file, cache_dir=cache_dir,
                         warn=warnings.append).info["map_cache"] == "built"
    assert "unreadable" in warnings[-1]


def test_the_cache_goes_to_the_xdg_cache_folder_and_says_when_it_cannot_be_written(map_files, tmp_path, monkeypatch):
    map_file = tmp_path / "map.pcd"
    map_file.write_bytes(map_files[0].read_bytes())
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    config = RegorConfig.preset("outdoor").replace({"features.voxel_size": 0.5})
    built = load_map_file(map_file, config)
    assert built.info["map_cache"] == "built"
    assert Path(built.info["map_cache_file"]).parent == tmp_path / "xdg" / "regor_ros"
    assert load_map_file(map_file, config).info["map_cache"] == "loaded"
    (tmp_path / "file").write_text("")
    warnings = []
    refused = load_map_file(map_file, config, cache_dir=tmp_path / "file" / "cache", warn=warnings.append)
    assert refused.info["map_cache"] == "not written" and "map cache not written" in warnings[0]


def test_cache_off_and_a_missing_file(map_files, tmp_path):
    map_file, _, _, _ = map_files
    config = RegorConfig.preset("outdoor").replace({"features.voxel_size": 0.6})
    off = load_map_file(map_file, config, cache=False)
    assert off.info["map_cache"] == "off" and "map_cache_file" not in off.info
    with pytest.raises(CloudFileError, match="no such file"):
        load_map_file(tmp_path / "nowhere.pcd", config)


def test_what_is_not_plausibly_a_map_is_refused_with_what_was_read(map_files, tmp_path):
    """A trajectory given as the map, random bytes as a KITTI .bin, and a path of points: each
    gets an error naming the file and what it holds, never a cache file."""
    config = RegorConfig.preset("outdoor")
    map_file, trajectory_file, _, _ = map_files
    as_text = tmp_path / "trajectory.txt"
    as_text.write_text(trajectory_file.read_text())
    garbage = tmp_path / "random.bin"
    garbage.write_bytes(np.random.default_rng(0).bytes(100_000))
    path = tmp_path / "path.npy"
    t = np.linspace(0.0, 60.0, 600)
    np.save(path, np.c_[t, 5 * np.sin(t / 10), np.zeros_like(t)])
    for refused, reason in ((as_text, "TUM trajectory"), (garbage, "NaN, infinite or beyond"),
                            (path, "a line gives 6")):
        with pytest.raises(CloudFileError, match=reason) as error:
            load_map_file(refused, config, cache_dir=tmp_path / "cache")
        assert str(refused) in str(error.value)
    assert not list(tmp_path.rglob("*.regor-cache.npz"))
    assert len(load_map_file(map_file, config, cache=False).prepared) > 1000


def test_a_map_too_sparse_for_the_preset_is_told_which_preset_fits(tmp_path):
    """A room's walls sampled about 0.12 m apart (a LiDAR map's spacing) refused by the indoor
    preset (5 cm voxels) with the preset whose scale fits, which then prepares it."""
    rng = np.random.default_rng(0)
    walls = []
    for axis in range(3):
        for side in (0.0, 1.0):
            wall = rng.uniform(0.0, 1.0, size=(4000, 3))
            wall[:, axis] = side
            walls.append(wall * [12.0, 10.0, 4.0])
    np.save(tmp_path / "room.npy", np.vstack(walls))
    with pytest.raises(CloudFileError, match="not a map of surfaces .*: the outdoor preset's scale fits"):
        load_map_file(tmp_path / "room.npy", RegorConfig.preset("indoor"), cache=False)
    assert len(load_map_file(tmp_path / "room.npy", RegorConfig.preset("outdoor"), cache=False).prepared) > 1000
