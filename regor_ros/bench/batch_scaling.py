"""regor-bench --batch: regor-batch's throughput against worker count, and its rows against serial.

The candidate list is what loop closure proposes within a session: every pair of the query scans of
each sequence in a maps folder (their poses give the truth), so each scan is in many pairs. It is
registered serially, register() pair by pair in one process (what a script does today), then by
regor-batch on a new local cluster of 1, 2, ... worker processes. Each batch row must equal the
serial one (same pose, same verdict).
"""
from __future__ import annotations

import itertools
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from ..core import RegorConfig, is_success, register
from ..io.cloud_io import read_cloud
from ..tools.batch import Progress, ResultFile, kernel_threads, open_client, run_batch
from ..tools.batch_list import read_pairs
from .results import write_results

CACHE_CLOUDS = 16  # regor-batch's default


def same_result(row: dict, result) -> bool:
    """Whether an output row holds exactly the pose and verdict register() gave."""
    return (not row.get("error") and row["accepted"] == result.accepted and row["reason"] == result.reason
            and np.array_equal(np.array(row["transform"]), result.transform))


def candidate_list(maps: Path, folder: Path) -> dict[str, np.ndarray]:
    """Write every within-sequence pair of query scans to ``folder/pairs.jsonl``; returns the truth
    (T_target_source) of each pair id."""
    truths, lines = {}, []
    for sequence in sorted(p.resolve() for p in maps.iterdir() if (p / "queries.json").is_file()):
        scans = [q["id"] for q in json.loads((sequence / "queries.json").read_text()) if q["kind"] == "scan"]
        for source, target in itertools.combinations(scans, 2):
            pair_id = f"{sequence.name}/{source}-{target}"
            poses = [np.loadtxt(sequence / "queries" / s / "gt.txt") for s in (source, target)]
            truths[pair_id] = np.linalg.inv(poses[1]) @ poses[0]
            lines.append(json.dumps({"id": pair_id, "source": str(sequence / "queries" / source / "scan.npy"),
                                     "target": str(sequence / "queries" / target / "scan.npy")}))
    (folder / "pairs.jsonl").write_text("\n".join(lines) + "\n")
    return truths


def _scored(name: str, seconds: float, accepted: list[bool], correct: list[bool], **extra) -> dict:
    return {"run": name, "pairs": len(accepted), "seconds": seconds, "pairs_per_s": len(accepted) / seconds,
            "published": sum(accepted),
            "published_correct": sum(a and c for a, c in zip(accepted, correct, strict=True)),
            "published_wrong": sum(a and not c for a, c in zip(accepted, correct, strict=True)), **extra}


def run_batch_scaling(maps: Path, workers: list[int], config: RegorConfig, overrides: dict, out: Path,
                      header: str) -> str:
    with tempfile.TemporaryDirectory() as scratch_name:
        scratch = Path(scratch_name)
        truths = candidate_list(maps, scratch)
        rows = read_pairs(scratch / "pairs.jsonl", default_preset="outdoor")
        print(f"{len(rows)} candidate pairs; serial register() ...", flush=True)
        start = time.perf_counter()
        serial = {r.id: register(read_cloud(r.source_path), read_cloud(r.target_path), config) for r in rows}
        serial_seconds = time.perf_counter() - start
        results = [_scored("serial register()", serial_seconds, [s.accepted for s in serial.values()],
                           [is_success(s.transform, truths[i], "outdoor") for i, s in serial.items()],
                           workers=0, start_seconds=0.0, identical=len(rows), reused=0)]
        for n in workers:
            print(f"regor-batch on {n} workers ...", flush=True)
            path = scratch / f"out-{n}.jsonl"
            start = time.perf_counter()
            client = open_client(n, None)
            client.wait_for_workers(n)
            started = time.perf_counter() - start
            try:
                run_batch(rows, ResultFile(path), overrides, client, CACHE_CLOUDS, Progress(len(rows), 0, False),
                          kernel_threads(n))
            finally:
                client.close()
            seconds = time.perf_counter() - start
            batch = {r["id"]: r for r in map(json.loads, path.read_text().splitlines())}
            results.append(_scored(
                f"regor-batch, {n} worker{'s' * (n > 1)}", seconds, [batch[r.id]["accepted"] for r in rows],
                [is_success(np.array(batch[r.id]["transform"]), truths[r.id], "outdoor") for r in rows],
                workers=n, start_seconds=started, reused=sum(b.get("reused", 0) for b in batch.values()),
                identical=sum(same_result(batch[i], s) for i, s in serial.items())))
    for r in results:
        r["speedup"] = r["pairs_per_s"] / results[0]["pairs_per_s"]
    lines = [header, "", "| run | pairs | seconds (cluster start) | pairs/s | vs serial | identical to serial "
             "| clouds reused | published correct / WRONG |", "|---|---|---|---|---|---|---|---|"]
    for r in results:
        lines.append(f"| {r['run']} | {r['pairs']} | {r['seconds']:.1f} ({r['start_seconds']:.1f}) | "
                     f"{r['pairs_per_s']:.2f} | {r['speedup']:.2f}x | {r['identical']}/{r['pairs']} | "
                     f"{r['reused']} of {2 * r['pairs']} | {r['published_correct']} / **{r['published_wrong']}** |")
    report = "\n".join(lines) + "\n"
    write_results(out, "batch_scaling", report, results, FIELDS, _plot)
    return report


FIELDS = ["run", "workers", "pairs", "seconds", "start_seconds", "pairs_per_s", "speedup", "identical", "reused",
          "published", "published_correct", "published_wrong"]


def _plot(results: list[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    batch = [r for r in results if r["workers"]]
    fig, ax = plt.subplots(figsize=(5, 3.5))
    ax.plot([r["workers"] for r in batch], [r["pairs_per_s"] for r in batch], "o-", label="regor-batch")
    ax.axhline(results[0]["pairs_per_s"], color="grey", ls="--", label="serial register()")
    ax.set_xlabel("local worker processes")
    ax.set_ylabel("pairs per second")
    ax.set_xticks([r["workers"] for r in batch])
    ax.set_ylim(bottom=0)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
