"""Feature-extraction benchmark on the visual maze (``scripts/bench_features.py``)."""

from __future__ import annotations

import time
from pathlib import Path

import gymnasium as gym
import numpy as np

from vistask.features import SiftExtractor, VisualFeatureExtractor
from vistask.logging import print_table, run_dir, write_summary


def bench_features(
    percepts: int = 2000,
    n_words: int = 2048,
    env_kwargs: dict | None = None,
    color_weights: tuple[float, ...] = (0.0, 0.5),
    threads: int | None = None,
    seed: int = 0,
    out: str | Path | None = None,
) -> dict:
    """Milliseconds and features per percept of the SIFT + vocabulary front end.

    Percepts are maze windows at random free positions. For each descriptor variant (grey
    SIFT, SIFT + chromaticity) it times keypoint extraction (batched, ``threads`` threads),
    vocabulary fitting, and assignment; the first variant's figures are the headline.
    """
    out = run_dir("bench_features", out)
    maze = gym.make("vistask/VisualMaze-v0", **(env_kwargs or {})).unwrapped
    positions = maze.geometry.sample_free(np.random.default_rng(seed), percepts)
    images = [maze.percept_at(p) for p in positions]
    variants = {}
    for color_weight in color_weights:
        keypoints = SiftExtractor(color_weight=color_weight, threads=threads)
        t0 = time.perf_counter()
        detected = keypoints.batch(images)
        t1 = time.perf_counter()
        extractor = VisualFeatureExtractor.fit(
            detected=detected,
            n_words=n_words,
            keypoints=keypoints,
            max_descriptors=20_000,
            iters=10,
            seed=seed,
        )
        t2 = time.perf_counter()
        presence = extractor.presence_of(detected)
        t3 = time.perf_counter()
        variants[f"color_weight={color_weight}"] = {
            "keypoints_ms_per_percept": 1e3 * (t1 - t0) / percepts,
            "assign_ms_per_percept": 1e3 * (t3 - t2) / percepts,
            "ms_per_percept": 1e3 * ((t1 - t0) + (t3 - t2)) / percepts,
            "vocabulary_fit_seconds": t2 - t1,
            "keypoints_per_percept": float(np.mean([len(k) for k in detected])),
            "features_per_percept": float(presence.sum(1).float().mean()),
            "vocabulary_size": extractor.n_features,
            "features_seen": int(presence.any(0).sum()),
        }
    headline = next(iter(variants.values()))
    summary = {
        "ms_per_percept": headline["ms_per_percept"],
        "features_per_percept": headline["features_per_percept"],
        "vocabulary_size": headline["vocabulary_size"],
        "percepts": percepts,
        "window": maze.window,
        "threads": SiftExtractor(threads=threads).threads,
        "variants": variants,
    }
    write_summary(out, summary)
    names = list(variants)
    print(f"{'figure':<28}" + "".join(f"{n:>22}" for n in names))
    for key in headline:
        print(f"{key:<28}" + "".join(f"{variants[n][key]:>22.4g}" for n in names))
    print_table({"percepts": percepts, "window": maze.window, "written": str(out / "summary.json")})
    return summary
