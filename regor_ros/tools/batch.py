"""regor-batch: register every pair of a candidate list on a Dask cluster, one output row per pair.

A fleet's back end verifies thousands of loop-closure and map-merging candidates; each row gets
Regor's pose and its verdict (accepted, or why not), the gate's figures and the seconds taken,
written to a JSON-lines file as each pair finishes. Nothing is lost: a rerun skips the rows the
file already holds, a killed worker's pairs are run again elsewhere (each row is written once,
by this process), and a pair that cannot be registered (a missing or unreadable file, a bad
viewpoint) gets a row with its error. Rows are the same as register() gives, whatever the
number of workers. Exit status: 0 every pair has a result, 1 some rows have an error, 2 the batch
could not run (the list, the output or the cluster).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections import OrderedDict, defaultdict
from pathlib import Path
from typing import TextIO

from ..core import PRESETS, ConfigError, RegorConfig
from .batch_list import ListError, PairRow, read_pairs
from .register_cli import DEFAULT_PRESET, PRESET_HELP, parse_overrides

IN_FLIGHT_PER_THREAD = 2  # one running, one queued: a worker never waits for the next pair
COUNTED = ("written", "accepted", "errors", "reused")  # what a run reports


class ResultFile:
    """The output, appended to and flushed row by row; what a previous run wrote is kept. A run
    that stopped mid-row leaves a partial last line, which is dropped (that pair runs again)."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.done: set[str] = set()
        self.errors: set[str] = set()  # rows with an error, this run's and before
        if self.path.is_file():
            self._keep_whole_rows()
        self._file: TextIO = open(self.path, "a", encoding="utf-8")

    def _keep_whole_rows(self) -> None:
        data = self.path.read_bytes()
        whole = data[:data.rfind(b"\n") + 1]
        if len(whole) != len(data):
            with open(self.path, "r+b") as f:
                f.truncate(len(whole))
        for number, line in enumerate(whole.decode("utf-8").splitlines(), 1):
            try:
                row = json.loads(line)
                self.done.add(str(row["id"]))
            except (ValueError, KeyError, TypeError):
                raise ListError(f"{self.path}: line {number} is not a regor-batch row; "
                                "give another --out, or remove the file to start again") from None
            if row.get("error"):
                self.errors.add(str(row["id"]))

    def write(self, row: dict) -> None:
        self._file.write(json.dumps(row) + "\n")
        self._file.flush()
        os.fsync(self._file.fileno())
        self.done.add(row["id"])
        if row.get("error"):
            self.errors.add(row["id"])

    def close(self) -> None:
        self._file.close()


class Dispatcher:
    """Which pair each worker gets next: one sharing the most clouds with those the worker
    prepared last (its cache), else the first pending. Dask alone would place pairs with no
    regard for the clouds a worker holds. A pair is only preferred for a worker, never tied to
    it: if the worker dies, the pair runs elsewhere."""

    def __init__(self, rows: list[PairRow], cache_capacity: int):
        self.pending: OrderedDict[str, PairRow] = OrderedDict((r.id, r) for r in rows)
        self._by_cloud: dict[tuple, set[str]] = defaultdict(set)
        for row in rows:
            for cloud in row.clouds():
                self._by_cloud[cloud].add(row.id)
        self._position = {row.id: i for i, row in enumerate(rows)}  # ties go to the earlier row
        self._capacity = cache_capacity
        self._recent: dict[str, OrderedDict[tuple, None]] = defaultdict(OrderedDict)  # worker -> clouds

    def __len__(self) -> int:
        return len(self.pending)

    def next_for(self, worker: str) -> PairRow:
        recent = self._recent[worker]
        shared: defaultdict = defaultdict(int)
        for cloud in recent:
            for row_id in self._by_cloud[cloud]:
                shared[row_id] += 1
        row_id = max(shared, key=lambda r: (shared[r], -self._position[r])) if shared else next(iter(self.pending))
        row = self.pending.pop(row_id)
        for cloud in row.clouds():
            self._by_cloud[cloud].discard(row_id)
            recent[cloud] = None
            recent.move_to_end(cloud)
            while len(recent) > self._capacity:
                recent.popitem(last=False)
        return row


class Progress:
    """Pairs done, rate and time left, on one line of stderr (every 10 s when not a terminal)."""

    def __init__(self, total: int, skipped: int, enabled: bool, stream=sys.stderr):
        self.total, self.skipped, self.enabled, self.stream = total, skipped, enabled, stream
        self.start = time.monotonic()
        self._last = 0.0
        self._tty = stream.isatty()

    def update(self, done: int, errors: int, workers: int, final: bool = False) -> None:
        now = time.monotonic()
        if not self.enabled or (not final and not self._tty and now - self._last < 10.0):
            return
        self._last = now
        elapsed = now - self.start
        rate = done / elapsed if elapsed > 0 else 0.0
        left = self.total - self.skipped - done
        eta = f"{left / rate:.0f} s" if rate > 0 else "?"
        width = 30
        filled = int(width * (self.skipped + done) / max(self.total, 1))
        line = (f"[{'#' * filled}{'.' * (width - filled)}] {self.skipped + done}/{self.total} pairs, "
                f"{rate:.2f} pairs/s, ETA {eta if left else '0 s'}, {workers} workers, {errors} errors")
        self.stream.write(("\r" + line + ("\n" if final else "")) if self._tty else line + "\n")
        self.stream.flush()


def _failed_row(row: PairRow, exc: BaseException) -> dict:
    """The row of a pair whose task itself failed: it killed every worker that ran it (out of
    memory, a crash in a native library) or raised what register_row does not expect."""
    from distributed import KilledWorker

    from .batch_worker import row_identity
    if isinstance(exc, KilledWorker):
        error = "the pair stopped every worker that ran it (out of memory, or a crash in a native library)"
    else:
        error = f"internal error: {type(exc).__name__}: {exc}"
    return {**row_identity(row), "accepted": False, "error": error}


def run_batch(rows: list[PairRow], results: ResultFile, overrides: dict[str, object], client,
              cache_capacity: int, progress: Progress, threads: int | None = None) -> dict[str, int]:
    """Register the rows not yet in ``results`` on the client's workers, each task with
    ``threads`` compiled-kernel threads (None: the worker's own); returns counts."""
    from distributed import as_completed

    from .batch_worker import register_row  # the core and its kernels: loaded once there is a batch to run
    counts = dict.fromkeys(COUNTED, 0)
    finished = as_completed()
    running: dict[object, tuple] = {}  # future -> (row, the worker it was sent to)
    load: dict[str, int] = defaultdict(int)
    dispatcher = Dispatcher([r for r in rows if r.id not in results.done], cache_capacity)

    def keep_workers_busy() -> int:
        workers = client.scheduler_info()["workers"]
        for address, info in workers.items():
            while dispatcher and load[address] < IN_FLIGHT_PER_THREAD * info.get("nthreads", 1):
                row = dispatcher.next_for(address)
                future = client.submit(register_row, row, overrides, cache_capacity, threads, pure=False,
                                       workers=[address], allow_other_workers=True)
                running[future] = (row, address)
                load[address] += 1
                finished.add(future)
        return len(workers)

    workers = keep_workers_busy()
    while dispatcher or running:
        if not running:  # every worker gone: wait for one (a nanny restarts a killed worker)
            client.wait_for_workers(1, timeout=120)
            workers = keep_workers_busy()
            continue
        future = next(finished)
        row, address = running.pop(future)
        load[address] -= 1
        try:
            out = future.result()
        except Exception as exc:  # the task failed, not the registration: still a row
            out = _failed_row(row, exc)
        results.write(out)
        counts["written"] += 1
        counts["accepted"] += bool(out.get("accepted"))
        counts["errors"] += bool(out.get("error"))
        counts["reused"] += out.get("reused", 0)
        progress.update(counts["written"], counts["errors"], workers)
        workers = keep_workers_busy()
    progress.update(counts["written"], counts["errors"], workers, final=True)
    return counts


def open_client(workers: int, scheduler: str | None):
    """A client of the cluster at ``scheduler``, or of a new local one on loopback with
    ``workers`` worker processes, each registering one pair at a time."""
    import logging

    from distributed import Client
    if scheduler:
        return Client(scheduler, timeout=30)
    with plain_worker_environment():  # a cluster the client makes is closed with it
        client = Client(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                        dashboard_address="127.0.0.1:0", silence_logs=logging.ERROR)
    from .batch_worker import QuietShutdown
    client.register_plugin(QuietShutdown())
    return client


def plain_worker_environment():
    """Dask config under which a local cluster's workers start with this process's environment
    (it is read when each worker's nanny is made, which restarts its worker so too). Dask sets
    two things before it starts a worker, and both change a registration:
    MALLOC_TRIM_THRESHOLD_=65536 turns off glibc's adaptive mmap threshold, so every large numpy
    array is mapped and unmapped afresh, and registrations took longer. OMP_NUM_THREADS=1 changed
    the bits when FAISS ran the exact feature search: it summed in an order that depends on the
    thread count, so a near tie between two features went either way, and poses differed in the last
    millimetres. FAISS still finds the cells a map query probes. (The nanny
    also writes these variables into this process's own environment, so nothing else goes here:
    the kernels' thread share is set per task, ``kernel_threads``.)"""
    import dask
    return dask.config.set({"distributed.nanny.pre-spawn-environ": {}})


def kernel_threads(workers: int) -> int:
    """Compiled-kernel threads for each of ``workers`` local workers: the cores shared out. Their
    results do not depend on the count, and two workers each spinning up every core ran at half
    the pairs per second (0.84 against 1.63 on 2 cores, 90 MulRan and Avia pairs)."""
    return max(1, (os.cpu_count() or 1) // max(workers, 1))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="regor-batch", description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="examples:\n  regor-batch candidates.csv --scans /data/scans --preset outdoor --out verified.jsonl\n"
               "  regor-batch closures.jsonl --out checked.jsonl --scheduler tcp://10.0.0.5:8786   # rows with a "
               "pose column are verified")
    parser.add_argument("pairs", help="the pair list: .csv with a header, or JSON lines "
                                      "(columns: source, target; optional id, source_viewpoint, target_viewpoint, "
                                      "preset)")
    parser.add_argument("--out", required=True, metavar="RESULTS.jsonl",
                        help="one JSON row per pair; rows already there are skipped (resume)")
    parser.add_argument("--scans", metavar="DIR", help="folder the list's file names are in (default: the list's "
                                                       "folder)")
    parser.add_argument("--preset", choices=PRESETS, default=DEFAULT_PRESET,
                        help=f"for rows that name none: {PRESET_HELP}")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="override a parameter of every row's preset (repeatable)")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                        help="worker processes of the local cluster (default: one per core)")
    parser.add_argument("--scheduler", metavar="ADDRESS",
                        help="use this Dask cluster instead (e.g. tcp://10.0.0.5:8786); its workers must "
                             "have regor_ros installed and see the files at the same paths")
    parser.add_argument("--cache-clouds", type=int, default=16, metavar="N",
                        help="prepared clouds each worker keeps for the pairs that share them (default: %(default)s)")
    parser.add_argument("--no-progress", action="store_true", help="no progress line on stderr")
    args = parser.parse_args(argv)
    if args.workers < 1 or args.cache_clouds < 1:
        parser.error("--workers and --cache-clouds must be at least 1")

    try:
        overrides = parse_overrides(args.set)
        rows = read_pairs(args.pairs, args.scans, args.preset)
        for preset in sorted({r.preset for r in rows if not r.error}):
            RegorConfig.preset(preset).replace(overrides).validate()
        results = ResultFile(Path(args.out))
    except (ConfigError, ListError, OSError) as exc:
        print(f"regor-batch: {exc}", file=sys.stderr)
        return 2
    skipped = sum(r.id in results.done for r in rows)
    progress = Progress(len(rows), skipped, not args.no_progress)
    start = time.perf_counter()
    client = None
    try:
        if skipped < len(rows):
            client = open_client(args.workers, args.scheduler)
            counts = run_batch(rows, results, overrides, client, args.cache_clouds, progress,
                               None if args.scheduler else kernel_threads(args.workers))
        else:
            counts = dict.fromkeys(COUNTED, 0)
    except (OSError, TimeoutError, RuntimeError) as exc:  # RuntimeError: a worker that cannot start
        print(f"regor-batch: the cluster failed ({exc}); rerun to resume", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"\nregor-batch: interrupted; {len(results.done)} of {len(rows)} rows are in {args.out}; "
              "rerun the same command to resume", file=sys.stderr)
        return 2
    finally:
        results.close()
        if client is not None:
            client.close()
    seconds = time.perf_counter() - start
    print(f"regor-batch: {len(rows)} pairs: {counts['written']} registered now ({counts['accepted']} accepted, "
          f"{counts['errors']} errors), {skipped} already in {args.out}; {seconds:.1f} s, "
          f"{counts['written'] / seconds:.2f} pairs/s; {counts['reused']} clouds reused")
    if results.errors:
        print(f"regor-batch: {len(results.errors)} rows of {args.out} have an error (see their "
              f"'error')", file=sys.stderr)
    return 1 if results.errors else 0


if __name__ == "__main__":
    raise SystemExit(main())
