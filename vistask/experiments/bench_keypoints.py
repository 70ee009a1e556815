"""Whether SIFT's keypoints of a maze view stay put as the view moves, by view size
(``scripts/bench_keypoints.py``)."""

from __future__ import annotations

import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from vistask.agents import RLVCAgent
from vistask.envs import VisualMazeEnv
from vistask.features import SiftExtractor
from vistask.features.keypoints import SIFT_NORM
from vistask.runs import print_table, run_dir, write_summary

SAME_DESCRIPTOR = 0.1 * SIFT_NORM  # a descriptor this close is the same detail's


def stay_put(
    extractor: SiftExtractor, tapestry: np.ndarray, window: int, views: int, shift: int, seed: int
) -> dict:
    """Keypoints of ``views`` square views of ``window`` pixels at random places of
    ``tapestry`` (H, W, 3), each against the same view moved ``shift`` pixels to the right.

    Returns:
        ``keypoints_per_view``; ``stay_put_share``: the share of them that the moved view shows
        at the same place of the tapestry (within half a pixel) with a descriptor within
        ``SAME_DESCRIPTOR``; ``stay_put_per_view``; ``ms_per_view`` (SIFT, one thread).
    """
    rng = np.random.default_rng(seed)
    corners = rng.integers(0, np.array(tapestry.shape[:2]) - window - shift, (views, 2))
    kept = total = 0
    seconds = 0.0
    for y, x in corners:
        t0 = time.perf_counter()
        here = extractor(tapestry[y : y + window, x : x + window])
        seconds += time.perf_counter() - t0
        moved = extractor(tapestry[y : y + window, x + shift : x + shift + window])
        back = moved.xy + np.float32([shift, 0])  # in the first view's pixels
        for xy, descriptor in zip(here.xy, here.descriptors, strict=True):
            same = np.linalg.norm(back - xy, axis=1) < 0.5
            distances = np.linalg.norm(moved.descriptors[same] - descriptor, axis=1)
            kept += bool(len(distances) and distances.min() < SAME_DESCRIPTOR)
        total += len(here)
    return {
        "keypoints_per_view": total / views,
        "stay_put_share": kept / max(total, 1),
        "stay_put_per_view": kept / views,
        "ms_per_view": 1e3 * seconds / views,
    }


def bench_keypoints(
    windows: tuple[int, ...] = (32, 48, 64, 96),
    enlarge: tuple[int, ...] = (1, 2),
    views: int = 300,
    shift: int = 4,
    seed: int = 0,
    out: str | Path | None = None,
) -> dict:
    """SIFT with ``RLVCAgent``'s settings on views of the maze's tapestry of each size in
    ``windows``, each view as it is and enlarged (``RLVCAgent(enlarge=e)``): keypoints a view,
    and how many of them a view moved ``shift`` pixels shows again (``stay_put``).
    ``summary[str(window)][str(enlarge)]`` holds ``stay_put``'s figures; ``stay_put.png`` plots
    them.
    """
    out = run_dir("bench_keypoints", out)
    tapestry = VisualMazeEnv().tapestry
    agent = RLVCAgent(None)  # its SIFT settings
    extractors = {
        factor: SiftExtractor(
            agent.contrast_threshold, agent.max_keypoints, threads=1, enlarge=factor
        )
        for factor in enlarge
    }
    summary: dict = {"views": views, "shift_pixels": shift, "seed": seed}
    for window in windows:
        summary[str(window)] = {}
        for factor, extractor in extractors.items():
            figures = stay_put(extractor, tapestry, window, views, shift, seed)
            summary[str(window)][str(factor)] = figures
            print_table(figures, f"window {window} px, enlarged {factor} times")
    _plot(summary, windows, enlarge, out / "stay_put.png")
    write_summary(out, summary)
    print_table({"written": str(out / "summary.json")})
    return summary


def _plot(summary: dict, windows, enlarge, path: Path) -> None:
    fig, ax = plt.subplots(figsize=(6, 3.5))
    width = 0.8 / len(enlarge)
    for i, factor in enumerate(enlarge):
        x = np.arange(len(windows)) + i * width
        rows = [summary[str(w)][str(factor)] for w in windows]
        ax.bar(x, [r["keypoints_per_view"] for r in rows], width, alpha=0.35, color=f"C{i}")
        ax.bar(
            x,
            [r["stay_put_per_view"] for r in rows],
            width,
            color=f"C{i}",
            label=("as it is" if factor == 1 else f"enlarged {factor} times")
            + ": staying put (pale: all)",
        )
    ax.set_xticks(
        np.arange(len(windows)) + width * (len(enlarge) - 1) / 2, [str(w) for w in windows]
    )
    ax.set_xlabel("view, pixels")
    ax.set_ylabel("keypoints a view")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
