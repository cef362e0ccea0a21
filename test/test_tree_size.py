"""The repository stays a package a robot's workspace clones, not an experiment archive: its
tracked files within a size budget, and no uncompressed file over a megabyte (run CSVs are kept
as .csv.gz; results/README.md says how to get back what left the tree)."""
import subprocess

import pytest
from conftest import REPO

BUDGET_BYTES = 12_000_000            # the whole tracked tree
MAX_UNCOMPRESSED_BYTES = 1_000_000   # one file that is not compressed
COMPRESSED = (".gz", ".png", ".npz")


def tracked() -> list:
    try:
        listing = subprocess.run(["git", "ls-files", "-z"], cwd=REPO, capture_output=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout: the tracked tree cannot be listed")
    return [REPO / name for name in listing.stdout.decode().split("\0") if name and (REPO / name).is_file()]


def test_the_tracked_tree_stays_within_its_budget():
    sizes = {path: path.stat().st_size for path in tracked()}
    total = sum(sizes.values())
    largest = sorted(sizes.items(), key=lambda item: -item[1])[:5]
    assert total <= BUDGET_BYTES, (f"{total / 1e6:.1f} MB tracked, budget {BUDGET_BYTES / 1e6:.0f} MB; "
                                   "largest: " + ", ".join(f"{p.relative_to(REPO)} {s / 1e6:.2f}" for p, s in largest))


def test_no_uncompressed_file_over_a_megabyte():
    big = [f"{path.relative_to(REPO)} ({path.stat().st_size / 1e6:.1f} MB)" for path in tracked()
           if path.stat().st_size > MAX_UNCOMPRESSED_BYTES and path.suffix not in COMPRESSED]
    assert not big, ("compress these (gzip: regor-calibrate-gate and lab/compare_runs.py read .csv.gz): "
                     + ", ".join(big))
