"""Time two versions of the code on the same registrations, alternating job by job: a fixed
60-pair sample of the 3DMatch/3DLoMatch lists (indoor preset) and every query of maps/ (outdoor
preset, single scans and fused sequences, each map prepared once). Each version runs in its own
worker process started from its own source tree.

Run from the repository root with the package's environment, the other version checked out
beside it (e.g. ``git worktree add /tmp/before HEAD~1``):
    python results/rivals/alternate.py ../shared/data /tmp/before . [--busy N]
``--busy N`` keeps N other processes spinning on the cores throughout, as a robot's other
software does.
"""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

SAMPLE, SEED = 60, 0
MAPS = ("fastlio_avia_hku2", "scaloam_mulran_kaist03")


def worker(data: Path, tree: str) -> None:
    """Register what stdin names ("pair INDEX" or "map SEQUENCE QUERY INPUT"), print the seconds,
    the verdict and the pose (its top three rows, every digit)."""
    sys.path.insert(0, tree)
    from regor_ros.core import RegorConfig, prepare_cloud, register
    from regor_ros.core.kernels import warm_up
    from regor_ros.tools.map_benchmark import load_sequence
    warm_up()
    lists = json.loads((data / "threedmatch" / "pairs.json").read_text())
    indoor, outdoor = RegorConfig.preset("indoor"), RegorConfig.preset("outdoor")
    maps = {}
    print("ready", flush=True)
    for line in sys.stdin:
        kind, *args = line.split()
        if kind == "pair":
            entry = lists[int(args[0])]
            folder = data / "threedmatch" / entry["scene"]
            result = register(np.load(folder / f"{entry['j']}.npy"), np.load(folder / f"{entry['i']}.npy"), indoor)
        else:
            sequence, query, which = args
            if sequence not in maps:
                points, trajectory, queries = load_sequence(data / "maps" / sequence)
                maps[sequence] = prepare_cloud(points, outdoor, "map", trajectory=trajectory), queries
            prepared, queries = maps[sequence]
            source = queries[int(query)].cloud(which)
            if source is None:   # a query without the scans before it and their odometry
                print("skip", flush=True)
                continue
            result = register(source, prepared, outdoor)
        pose = " ".join(repr(float(x)) for x in result.transform[:3].ravel())
        print(f"{result.timings['total']:.5f} {int(result.accepted)} {pose}", flush=True)


def jobs(data: Path) -> list[str]:
    """The sample's pairs, then every map query that has the input."""
    pairs = np.random.default_rng(SEED).choice(len(json.loads((data / "threedmatch" / "pairs.json").read_text())),
                                               SAMPLE, replace=False)
    out = [f"pair {i}" for i in pairs]
    for sequence in MAPS:
        for n, query in enumerate(json.loads((data / "maps" / sequence / "queries.json").read_text())):
            out.append(f"map {sequence} {n} single")
            if query["kind"] == "scan" and query.get("sequence"):
                out.append(f"map {sequence} {n} sequence")
    return out


def main(data: Path, before: str, after: str, busy: int) -> None:
    spinning = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(busy)]
    try:
        compare(data, {"before": before, "after": after})
    finally:
        for process in spinning:
            process.kill()


def compare(data: Path, versions: dict) -> None:
    workers = {name: subprocess.Popen([sys.executable, __file__, "--worker", str(data), tree],
                                      stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
               for name, tree in versions.items()}
    for w in workers.values():
        assert w.stdout.readline().startswith("ready")
    seconds = {name: {"pair": [], "map": []} for name in versions}
    verdicts_differ, poses_differ, largest = 0, 0, 0.0
    for k, job in enumerate(jobs(data)):
        answers = {}
        for name in (("before", "after") if k % 2 == 0 else ("after", "before")):
            workers[name].stdin.write(job + "\n")
            workers[name].stdin.flush()
            answers[name] = workers[name].stdout.readline().split()
        if answers["before"] == ["skip"]:
            continue
        verdicts_differ += answers["before"][1] != answers["after"][1]
        poses = {name: np.array(answer[2:], dtype=float) for name, answer in answers.items()}
        poses_differ += not np.array_equal(poses["before"], poses["after"])
        largest = max(largest, float(np.abs(poses["before"] - poses["after"]).max()))
        for name, (value, *_) in answers.items():
            seconds[name][job.split()[0]].append(float(value))
    for kind in ("pair", "map"):
        b, a = np.array(seconds["before"][kind]), np.array(seconds["after"][kind])
        print(f"{kind}s ({len(b)}): median {np.median(b):.3f} s before, {np.median(a):.3f} s after "
              f"(ratio {np.median(a) / np.median(b):.3f}; median of the differences {np.median(a - b):+.4f} s)")
    print(f"verdicts that differ: {verdicts_differ}")
    print(f"poses that differ: {poses_differ} (largest difference of an entry {largest:.3g})")


if __name__ == "__main__":
    if sys.argv[1] == "--worker":
        worker(Path(sys.argv[2]), sys.argv[3])
    else:
        busy = int(sys.argv[sys.argv.index("--busy") + 1]) if "--busy" in sys.argv else 0
        main(Path(sys.argv[1]), sys.argv[2], sys.argv[3], busy)
