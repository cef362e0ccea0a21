"""regor-register end to end: every reader, a real pair from files, errors, the picture."""
import json
import os
import shutil
import struct
import subprocess
import sys

import numpy as np
import open3d as o3d
import pytest
from conftest import moved_pair

from regor_ros.core.metrics import is_success
from regor_ros.io.cloud_io import CloudFileError, read_cloud
from regor_ros.tools.picture import PICTURE_SIZE

POINTS = np.random.default_rng(0).uniform(-1, 1, size=(200, 3))


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "regor_ros.tools.register_cli", *map(str, args)],
                          capture_output=True, text=True, timeout=300)


def write_ply(path, points, ascii_format):
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    assert o3d.io.write_point_cloud(str(path), pcd, write_ascii=ascii_format)


@pytest.mark.parametrize("ascii_format", [True, False])
def test_reads_ascii_and_binary_ply(tmp_path, ascii_format):
    path = tmp_path / "cloud.ply"
    write_ply(path, POINTS, ascii_format)
    assert (b"format ascii" in path.read_bytes()[:200]) == ascii_format
    np.testing.assert_allclose(read_cloud(path), POINTS, atol=1e-6)


def test_reads_pcd_xyz_txt_npy_and_kitti_bin(tmp_path):
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(POINTS))
    o3d.io.write_point_cloud(str(tmp_path / "c.pcd"), pcd)
    np.savetxt(tmp_path / "c.xyz", POINTS)
    np.savetxt(tmp_path / "c.txt", np.c_[POINTS, np.ones(len(POINTS))], delimiter=" ")
    np.save(tmp_path / "c.npy", POINTS)
    np.c_[POINTS, np.zeros(len(POINTS))].astype("<f4").tofile(tmp_path / "c.bin")
    for name, tol in [("c.pcd", 1e-6), ("c.xyz", 1e-12), ("c.txt", 1e-12), ("c.npy", 0), ("c.bin", 1e-6)]:
        np.testing.assert_allclose(read_cloud(tmp_path / name), POINTS, atol=tol, err_msg=name)


@pytest.mark.parametrize("name, content, message", [
    ("empty.ply", b"", "empty"),
    ("junk.pcd", b"this is not a point cloud\n", "no points could be read"),
    ("short.bin", struct.pack("<3f", 1, 2, 3), "whole number of KITTI points"),
    ("words.xyz", b"a b c\n", "not a table of numbers"),
    ("cloud.las", b"LASF", "unknown format"),
])
def test_unreadable_files_raise_a_clear_error(tmp_path, name, content, message):
    (tmp_path / name).write_bytes(content)
    with pytest.raises(CloudFileError, match=message):
        read_cloud(tmp_path / name)


@pytest.fixture(scope="module")
def real_files(tmp_path_factory):
    """A real pair, source written as binary ply and target as KITTI bin, with its truth."""
    folder = tmp_path_factory.mktemp("pair")
    src, tgt, T_gt, _ = moved_pair("3dmatch_redkitchen_0_5_ds", 31)
    write_ply(folder / "src.ply", src, ascii_format=False)
    np.c_[tgt, np.zeros(len(tgt))].astype("<f4").tofile(folder / "tgt.bin")
    np.savetxt(folder / "gt.txt", T_gt)
    return folder, T_gt


def test_registers_a_real_pair_from_files(real_files):
    folder, T_gt = real_files
    out = folder / "T.txt"
    picture = folder / "picture.png"
    proc = run_cli(folder / "src.ply", folder / "tgt.bin", "--ground-truth", folder / "gt.txt",
                   "--output", out, "--picture", picture, "--set", "seed=3")
    assert proc.returncode == 0, proc.stderr
    assert "T_target_source" in proc.stdout and "rotation" in proc.stdout and "accepted" in proc.stdout
    assert is_success(np.loadtxt(out), T_gt, "indoor")
    header = picture.read_bytes()[:24]
    assert header[:8] == b"\x89PNG\r\n\x1a\n"
    assert struct.unpack(">II", header[16:24]) == PICTURE_SIZE


def test_json_output(real_files):
    folder, T_gt = real_files
    proc = run_cli(folder / "src.ply", folder / "tgt.bin", "--json", "--ground-truth", folder / "gt.txt")
    rep = json.loads(proc.stdout)
    assert proc.returncode == (0 if rep["accepted"] else 1)
    assert np.array(rep["transform"]).shape == (4, 4)
    assert rep["rotation_error_deg"] < 15 and set(rep["timings"]) >= {"features", "total"}


@pytest.mark.parametrize("make, message", [
    (lambda d: d / "missing.npy", "no such file"),
    (lambda d: (d / "empty.pcd").write_bytes(b"") or d / "empty.pcd", "empty"),
    (lambda d: np.save(d / "few.npy", np.zeros((5, 3))) or d / "few.npy", "too few points to register (5;"),
    (lambda d: np.save(d / "heap.npy", np.zeros((500, 3))) or d / "heap.npy", "after downsampling"),
    (lambda d: (d / "bad.pcd").write_text("garbage\n") and d / "bad.pcd", "no points could be read"),  # open3d quiet
    (lambda d: np.save(d / "none.npy", np.zeros((0, 3), np.float32)) or d / "none.npy", "no points (an empty array)"),
    (lambda d: (d / "random.bin").write_bytes(np.random.default_rng(0).bytes(4000)) and d / "random.bin",
     "not a point cloud (random bytes"),
])
def test_bad_inputs_exit_nonzero_with_one_line(tmp_path, make, message):
    np.save(tmp_path / "ok.npy", POINTS)
    proc = run_cli(make(tmp_path), tmp_path / "ok.npy")
    assert proc.returncode == 2
    assert message in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and "Traceback" not in proc.stderr


def test_bad_override_is_reported(tmp_path):
    np.save(tmp_path / "ok.npy", POINTS)
    proc = run_cli(tmp_path / "ok.npy", tmp_path / "ok.npy", "--set", "voxel_size=-3")
    assert proc.returncode == 2 and "features.voxel_size" in proc.stderr


@pytest.mark.parametrize("tool", ["regor-register", "regor-bench", "regor-calibrate-gate"])
def test_the_readme_commands_run_as_written_after_set_up(tool):
    """scripts/setup.sh puts the tools on the virtual environment's PATH (the README's commands)."""
    path = shutil.which(tool)
    assert path, f"{tool} is not on PATH: run scripts/setup.sh and activate .venv"
    done = subprocess.run([path, "--help"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and "usage:" in done.stdout, done.stderr


def test_random_bytes_as_npy_get_no_pickle_advice(tmp_path):
    path = tmp_path / "noise.npy"
    path.write_bytes(np.random.default_rng(1).bytes(512))
    with pytest.raises(CloudFileError) as error:
        read_cloud(path)
    assert "not a numpy .npy array file" in str(error.value) and "pickle" not in str(error.value)


def test_relocalize_with_a_missing_scan_says_so_in_one_line_and_exits_2(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "regor_ros.tools.relocalize_client", "--scan",
                           str(tmp_path / "missing.npy"), "--timeout", "1"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip() == f"regor-relocalize: {tmp_path / 'missing.npy'}: no such file"


def test_relocalize_with_no_node_running_says_so_without_waiting_for_the_answer_timeout():
    """No register_node on this domain: the service is looked for --find-within seconds, not the
    whole --timeout an answer may take."""
    env = {**os.environ, "ROS_DOMAIN_ID": str((int(os.environ["ROS_DOMAIN_ID"]) + 37) % 100)}
    proc = subprocess.run([sys.executable, "-m", "regor_ros.tools.relocalize_client", "--find-within", "1",
                           "--timeout", "3600"], capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 2, proc.stderr
    assert "regor-relocalize: no service /register_node/relocalize within 1 s" in proc.stderr.splitlines()[-1]


def test_bench_help_shows_examples_and_the_data_formats_and_writes_beside_the_committed_results():
    proc = subprocess.run([sys.executable, "-m", "regor_ros.bench.cli", "--help"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0
    assert "regor-bench --threedmatch ../shared/data/threedmatch --sample 200" in proc.stdout
    assert 'pairs.json, a list of {"name", "kind"' in proc.stdout and "default: bench-out" in proc.stdout


def test_the_preset_help_names_the_sensors_and_the_default():
    proc = subprocess.run([sys.executable, "-m", "regor_ros.tools.register_cli", "--help"],
                          capture_output=True, text=True, timeout=300)
    assert "default: indoor" in proc.stdout and "LiDAR" in proc.stdout


@pytest.mark.parametrize("tool, args", [
    ("verify_cli", ["{empty}", "{ok}", "{pose}"]),
    ("verify_cli", ["{ok}", "{empty}", "{pose}"]),
    ("relocalize_client", ["--scan", "{empty}", "--timeout", "1"]),
])
def test_an_empty_npy_is_refused_in_one_line_by_every_tool(tmp_path, tool, args):
    files = {"empty": tmp_path / "empty.npy", "ok": tmp_path / "ok.npy", "pose": tmp_path / "pose.txt"}
    np.save(files["empty"], np.zeros((0, 3), np.float32))
    np.save(files["ok"], POINTS)
    np.savetxt(files["pose"], np.eye(4))
    proc = subprocess.run([sys.executable, "-m", f"regor_ros.tools.{tool}", *[a.format(**files) for a in args]],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and "empty.npy: no points (an empty array)" in proc.stderr, proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and "Traceback" not in proc.stderr
