"""regor-batch on a real Dask cluster on loopback: rows as register() gives them, bad rows, a
resumed batch, a worker killed mid-batch; and the pair list and the dispatcher on their own."""
import json
import logging
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import DATA, require_shared_data

from regor_ros.bench.batch_scaling import same_result
from regor_ros.core import RegorConfig, register
from regor_ros.tools.batch import Dispatcher, ResultFile, plain_worker_environment
from regor_ros.tools.batch_list import ListError, read_pairs

SCANS = DATA / "maps" / "scaloam_mulran_kaist03" / "queries"
# place recognition's candidates among five scans of a drive: each scan is in several pairs
GOOD = [("1-3", 1, 3), ("1-5", 1, 5), ("3-5", 3, 5), ("3-7", 3, 7), ("5-7", 5, 7), ("5-9", 5, 9), ("7-9", 7, 9)]


def scan(number):
    return f"scan_{number:06d}/scan.npy"


def write_list(path, bad_rows=True):
    lines = ["id,source,target,source_viewpoint,preset"]
    lines += [f"{name},{scan(a)},{scan(b)},," for name, a, b in GOOD]
    if bad_rows:
        lines += [f"missing,{scan(1)},scan_999999/scan.npy,,",
                  f"broken,{scan(1)},broken.pcd,,",
                  f"viewpoint,{scan(1)},{scan(3)},\"1, 2\",",
                  f"preset,{scan(1)},{scan(3)},,underwater"]
    path.write_text("\n".join(lines) + "\n")
    return path


def run_batch(*args, timeout=600):
    return subprocess.run([sys.executable, "-m", "regor_ros.tools.batch", *map(str, args), "--preset", "outdoor"],
                          capture_output=True, text=True, timeout=timeout)


def rows_of(path):
    return [json.loads(line) for line in Path(path).read_text().splitlines()]


@pytest.fixture(scope="module")
def scans(tmp_path_factory):
    """The scans folder with a broken file added beside links to the real scans."""
    require_shared_data("batch scans")
    folder = tmp_path_factory.mktemp("scans")
    for number in {n for _, a, b in GOOD for n in (a, b)}:
        (folder / scan(number)).parent.mkdir()
        (folder / scan(number)).symlink_to(SCANS / scan(number))
    (folder / "broken.pcd").write_bytes(b"not a point cloud\x00\x01")
    return folder


@pytest.fixture(scope="module")
def serial(scans):
    """register() on each good pair, in this process: what every batch row must equal."""
    config = RegorConfig.preset("outdoor")
    return {name: register(np.load(scans / scan(a)), np.load(scans / scan(b)), config) for name, a, b in GOOD}


@pytest.fixture(scope="module")
def first_run(scans, tmp_path_factory):
    folder = tmp_path_factory.mktemp("batch")
    out = folder / "out.jsonl"
    done = run_batch(write_list(folder / "pairs.csv"), "--scans", scans, "--out", out, "--workers", 2)
    return done, out


def check_rows(rows, serial):
    ids = [r["id"] for r in rows]
    assert len(ids) == len(set(ids)), f"a row written twice: {ids}"
    for name, result in serial.items():
        row = next(r for r in rows if r["id"] == name)
        assert same_result(row, result), (name, row.get("error"), row.get("reason"))


def test_two_workers_give_register_s_rows_and_bad_rows_get_an_error(first_run, serial):
    done, out = first_run
    assert done.returncode == 1, done.stderr  # 1: some rows have an error, the batch went on
    rows = rows_of(out)
    expected = [n for n, _, _ in GOOD] + ["missing", "broken", "viewpoint", "preset"]
    assert sorted(r["id"] for r in rows) == sorted(expected)
    check_rows(rows, serial)
    errors = {r["id"]: r["error"] for r in rows if r["error"]}
    assert set(errors) == {"missing", "broken", "viewpoint", "preset"}
    assert "no such file" in errors["missing"] and "broken.pcd" in errors["broken"]
    assert "source_viewpoint" in errors["viewpoint"] and "underwater" in errors["preset"]
    assert "Traceback" not in done.stderr
    good = [r for r in rows if not r["error"]]
    assert len({r["worker"] for r in good}) == 2, "both workers registered pairs"
    # seven pairs over five scans: the workers reuse clouds they prepared
    assert sum(r["reused"] for r in good) >= 4
    assert all(len(r["transform"]) == 4 and r["figures"]["fitness"] > 0 and r["seconds"] > 0 for r in good)
    assert "11 registered now" in done.stdout, done.stdout


def test_a_rerun_resumes_and_skips_the_rows_already_written(first_run, serial, scans, tmp_path):
    _, first = first_run
    lines = first.read_text().splitlines(keepends=True)
    out = tmp_path / "out.jsonl"
    out.write_text("".join(lines[:4]) + lines[4][:len(lines[4]) // 2])  # stopped while writing a row
    done = run_batch(write_list(tmp_path / "pairs.csv"), "--scans", scans, "--out", out, "--workers", 1)
    assert done.returncode == 1, done.stderr
    assert "7 registered now" in done.stdout and "4 already in" in done.stdout, done.stdout
    text = out.read_text()
    assert text.startswith("".join(lines[:4]))
    rows = rows_of(out)
    assert len(rows) == len(lines)
    check_rows(rows, serial)
    again = run_batch(tmp_path / "pairs.csv", "--scans", scans, "--out", out)
    assert "0 registered now" in again.stdout and out.read_text() == text


def test_a_worker_killed_mid_batch_loses_and_duplicates_no_row(scans, serial, tmp_path):
    from distributed import Client, LocalCluster
    numba_threads = os.environ.get("NUMBA_NUM_THREADS")
    with plain_worker_environment():  # an existing cluster, set up as regor-batch's own
        cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address="127.0.0.1:0", silence_logs=logging.ERROR)
    # the nanny writes its workers' variables into this process: a changed NUMBA_NUM_THREADS makes
    # numba refuse every later compile here
    assert os.environ.get("NUMBA_NUM_THREADS") == numba_threads
    client = Client(cluster)
    out = tmp_path / "out.jsonl"
    try:
        pids = client.run(os.getpid)
        batch = subprocess.Popen([sys.executable, "-m", "regor_ros.tools.batch",
                                  str(write_list(tmp_path / "pairs.csv", False)),
                                  "--scans", str(scans), "--out", str(out), "--preset", "outdoor",
                                  "--scheduler", cluster.scheduler_address, "--no-progress"],
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 300
        while (not out.is_file() or not out.read_text()) and time.monotonic() < deadline and batch.poll() is None:
            time.sleep(0.05)
        busy = [address for address, keys in client.processing().items() if keys]
        assert busy and batch.poll() is None, "the batch ended before a worker could be killed"
        written = len(rows_of(out))
        os.kill(pids[busy[0]], signal.SIGKILL)  # mid-batch, while it runs a pair
        stdout, stderr = batch.communicate(timeout=600)
        assert batch.returncode == 0, stderr
        assert written < len(GOOD)
        rows = rows_of(out)
        assert len(rows) == len(GOOD)
        check_rows(rows, serial)
    finally:
        client.close()
        cluster.close()


def test_a_pair_list_in_json_lines(tmp_path):
    path = tmp_path / "pairs.jsonl"
    path.write_text('{"source": "a.npy", "target": "b.npy", "target_viewpoint": null}\n'
                    '\n'
                    '{"id": "x", "source": "a.npy", "target": "c.npy", "source_viewpoint": [1, 2, 3]}\n'
                    'not json\n'
                    '{"source": "a.npy"}\n')
    rows = read_pairs(path, default_preset="outdoor")
    assert [r.id for r in rows] == ["1", "x", "4", "5"]
    assert rows[0].target_viewpoint is None and rows[0].source_viewpoint == (0.0, 0.0, 0.0)
    assert rows[0].source_path == tmp_path / "a.npy" and rows[0].preset == "outdoor"
    assert rows[1].source_viewpoint == (1.0, 2.0, 3.0)
    assert "not JSON" in rows[2].error and "both a source and a target" in rows[3].error


@pytest.mark.parametrize("text, message", [
    ("src,tgt\na,b\n", "must name the columns source and target"),
    ("id,source,target\nx,a,b\nx,a,c\n", "ids must be unique"),
    ("source,target\n", "no pairs"),
])
def test_a_pair_list_that_cannot_be_used_is_refused(tmp_path, text, message):
    (tmp_path / "pairs.csv").write_text(text)
    with pytest.raises(ListError, match=message):
        read_pairs(tmp_path / "pairs.csv")
    done = run_batch(tmp_path / "pairs.csv", "--out", tmp_path / "out.jsonl")
    assert done.returncode == 2 and message in done.stderr and "Traceback" not in done.stderr


def test_an_output_that_is_not_a_batch_s_is_refused(tmp_path):
    (tmp_path / "out.jsonl").write_text("hello\n")
    with pytest.raises(ListError, match="not a regor-batch row"):
        ResultFile(tmp_path / "out.jsonl")


def test_the_dispatcher_sends_a_worker_the_pairs_sharing_its_clouds(tmp_path):
    (tmp_path / "pairs.csv").write_text("id,source,target\na,s1,t1\nb,s2,t2\nc,s3,t1\nd,s2,t3\ne,s4,t4\n")
    dispatcher = Dispatcher(read_pairs(tmp_path / "pairs.csv"), cache_capacity=4)
    first, second = dispatcher.next_for("w1").id, dispatcher.next_for("w2").id
    assert (first, second) == ("a", "b")
    assert dispatcher.next_for("w1").id == "c"  # shares t1 with a
    assert dispatcher.next_for("w2").id == "d"  # shares s2 with b
    assert dispatcher.next_for("w1").id == "e" and not dispatcher


def test_a_closing_worker_s_failed_heartbeat_is_not_logged_a_running_one_s_is(caplog):
    """Closing the local cluster, a heartbeat in flight meets the worker's own closed connections
    (dask/distributed#7105): not an error after a finished batch; while running it is one."""
    from types import SimpleNamespace

    from distributed.core import Status

    from regor_ros.tools.batch_worker import QuietShutdown
    logger = logging.getLogger("distributed.worker")
    worker = SimpleNamespace(status=Status.running)
    before = list(logger.filters)
    QuietShutdown().setup(worker)
    try:
        with caplog.at_level(logging.ERROR, logger="distributed.worker"):
            logger.error("Failed to communicate with scheduler during heartbeat.")
            worker.status = Status.closing
            logger.error("Failed to communicate with scheduler during heartbeat.")
            logger.error("Unexpected exception during heartbeat. Closing worker.")
    finally:
        logger.filters[:] = before
    assert [(r.getMessage(), r.levelno) for r in caplog.records] == [
        ("Failed to communicate with scheduler during heartbeat.", logging.ERROR),
        ("Unexpected exception during heartbeat. Closing worker.", logging.ERROR)]


def test_a_list_with_poses_is_verified(scans, tmp_path):
    """A SLAM back end's loop closures come with their poses: each row's pose is verified."""
    truth = {n: np.loadtxt(SCANS / f"scan_{n:06d}" / "gt.txt") for n in (1, 3, 5)}

    def between(target, source, shift=0.0):
        T = np.linalg.inv(truth[target]) @ truth[source]
        T[0, 3] += shift
        return " ".join(f"{v:.9f}" for v in T.ravel())

    path = tmp_path / "closures.csv"
    path.write_text("id,source,target,pose\n"
                    f"right-1-3,{scan(3)},{scan(1)},{between(1, 3)}\n"
                    f"right-3-5,{scan(5)},{scan(3)},{between(3, 5)}\n"
                    f"wrong-1-3,{scan(3)},{scan(1)},{between(1, 3, shift=5.0)}\n"
                    f"bad,{scan(3)},{scan(1)},1 2 3\n")
    out = tmp_path / "verified.jsonl"
    done = run_batch(path, "--scans", scans, "--out", out, "--workers", 1, "--no-progress")
    assert done.returncode == 1, done.stderr   # the bad row has an error
    rows = {r["id"]: r for r in rows_of(out)}
    assert rows["right-1-3"]["accepted"] and rows["right-3-5"]["accepted"], rows
    wrong = rows["wrong-1-3"]
    assert not wrong["accepted"] and wrong["reason"], wrong
    assert wrong["given"][0][3] == rows["right-1-3"]["given"][0][3] + 5.0   # the pose as given, and the refined one
    assert "expected 16 numbers" in rows["bad"]["error"]


def test_a_pose_column_reads_a_matrix_or_a_quaternion(tmp_path):
    path = tmp_path / "pairs.jsonl"
    path.write_text('{"source": "a.npy", "target": "b.npy", "pose": [[1,0,0,2],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}\n'
                    '{"source": "a.npy", "target": "b.npy", "pose": "2 0 0 0 0 0 1"}\n'
                    '{"source": "a.npy", "target": "b.npy"}\n')
    rows = read_pairs(path)
    assert rows[0].pose == rows[1].pose and rows[0].pose[3] == 2.0
    assert rows[2].pose is None and not rows[2].error
