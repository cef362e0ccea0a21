"""A headless picture of a registration: the clouds before and after alignment, and the
correspondences, each seen from above and from the side."""
from __future__ import annotations

import numpy as np

from ..core import RegistrationResult, transform_points

PICTURE_SIZE = (1500, 900)  # pixels
MAX_POINTS = 15000
MAX_LINES = 300
VIEWS = (("top (x, y)", (0, 1)), ("side (x, z)", (0, 2)))
AGREE, DISAGREE = (0.1, 0.7, 0.2, 0.9), (0.9, 0.1, 0.1, 0.35)   # RGBA of the correspondence lines


def _thin(points: np.ndarray, rng) -> np.ndarray:
    return points if len(points) <= MAX_POINTS else points[rng.choice(len(points), MAX_POINTS, replace=False)]


def render(source: np.ndarray, target: np.ndarray, result: RegistrationResult, path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection
    from matplotlib.lines import Line2D

    rng = np.random.default_rng(0)
    T = result.transform
    src, tgt = _thin(source, rng), _thin(target, rng)
    aligned = transform_points(T, src)
    # correspondences: the aligned source shifted sideways, lines to the target keypoints
    shift = np.array([1.2 * np.ptp(target[:, 0]) + 1e-6, 0.0, 0.0])
    match_src = transform_points(T, result.initial.source) + shift
    inlier = result.initial.inlier
    pick = np.r_[np.flatnonzero(inlier)[:MAX_LINES // 2], np.flatnonzero(~inlier)[:MAX_LINES // 2]]

    dpi = 100
    fig, axes = plt.subplots(2, 3, figsize=(PICTURE_SIZE[0] / dpi, PICTURE_SIZE[1] / dpi), dpi=dpi)
    for row, (view, (a, b)) in enumerate(VIEWS):
        panels = [("before", src, tgt), ("after", aligned, tgt), ("correspondences", aligned + shift, tgt)]
        for col, (title, s, t) in enumerate(panels):
            ax = axes[row, col]
            ax.scatter(t[:, a], t[:, b], s=0.3, c="tab:blue", alpha=0.5, linewidths=0, label="target")
            ax.scatter(s[:, a], s[:, b], s=0.3, c="tab:orange", alpha=0.5, linewidths=0, label="source")
            if title == "correspondences":   # the disagreeing matches under the agreeing ones
                segments = np.stack([match_src[pick][:, [a, b]], result.initial.target[pick][:, [a, b]]], axis=1)
                agree = inlier[pick]
                ax.add_collection(LineCollection(segments[~agree], colors=[DISAGREE], linewidths=0.5, zorder=2))
                ax.add_collection(LineCollection(segments[agree], colors=[AGREE], linewidths=0.7, zorder=3))
            names = "xyz"
            ax.set_title(f"{title}: {view}", fontsize=10)
            ax.set_xlabel(f"{names[a]} [m]", fontsize=8)
            ax.set_ylabel(f"{names[b]} [m]", fontsize=8)
            ax.set_aspect("equal", adjustable="datalim")
            ax.tick_params(labelsize=7)
    axes[0, 0].legend(loc="upper right", fontsize=7, markerscale=15)
    axes[0, 2].legend(handles=[Line2D([], [], color=AGREE, label="feature matches that agree with the pose"),
                               Line2D([], [], color=DISAGREE, label="feature matches that do not")],
                      loc="upper right", fontsize=7)
    verdict = "accepted" if result.accepted else f"NOT accepted: {result.reason}"
    fig.suptitle(f"{result.num_inliers} inliers, fitness {result.fitness:.2f}, "
                 f"{result.feature_inliers} feature matches agree - {verdict}", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
