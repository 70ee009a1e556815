"""Feature-extraction benchmark on the visual maze (``scripts/bench_features.py``)."""

from __future__ import annotations

import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

import vistask.envs  # noqa: F401  (registers the maze)
from vistask.features import SiftExtractor, VisualFeatureExtractor
from vistask.runs import print_table, run_dir, write_summary

# name -> (colour weight of the descriptors, coarse groups of the vocabulary; 0: flat)
VARIANTS = {
    "grey SIFT, 64 groups (default)": (0.0, 64),
    "grey SIFT, flat": (0.0, 0),
    "SIFT + chromaticity, 64 groups": (0.5, 64),
}


def bench_features(
    percepts: int = 2000,
    n_words: int = 8192,
    env_kwargs: dict | None = None,
    variants: dict[str, tuple[float, int]] | None = None,
    threads: int | None = None,
    seed: int = 0,
    out: str | Path | None = None,
) -> dict:
    """Milliseconds and features per percept of the SIFT + vocabulary front end.

    Percepts are maze windows at random free positions. For each variant (descriptor colour
    weight, vocabulary groups) it times keypoint extraction (batched, ``threads`` threads),
    vocabulary fitting, and word assignment: in one batch, in batches of 16 views (what 16
    envs side by side match) and one view at a time (a single env's loop); the first
    variant's figures are the headline.
    ``exact_nearest_share`` is the share of descriptors given their nearest prototype (1 for a
    flat vocabulary; a grouped one searches only the prototypes of a few groups).
    """
    out = run_dir("bench_features", out)
    maze = gym.make("vistask/VisualMaze-v0", **(env_kwargs or {})).unwrapped
    positions = maze.geometry.sample_free(np.random.default_rng(seed), percepts)
    images = [maze.percept_at(p) for p in positions]
    results = {}
    for name, (color_weight, groups) in (variants or VARIANTS).items():
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
            groups=groups,
            seed=seed,
        )
        t2 = time.perf_counter()
        presence = extractor.presence_of(detected)
        t3 = time.perf_counter()
        for s in range(0, len(detected), 16):
            extractor.presence_of(detected[s : s + 16])
        t4 = time.perf_counter()
        singles = detected[:200]
        for one in singles:
            extractor.presence_of([one])
        t5 = time.perf_counter()
        x = torch.from_numpy(np.concatenate([k.descriptors for k in detected]))
        exact = VisualFeatureExtractor(keypoints, extractor.centroids).nearest(x)[0]
        results[name] = {
            "keypoints_ms_per_percept": 1e3 * (t1 - t0) / percepts,
            "assign_ms_per_percept": 1e3 * (t3 - t2) / percepts,
            "assign_ms_per_percept_batches_of_16": 1e3 * (t4 - t3) / percepts,
            "assign_ms_one_percept_at_a_time": 1e3 * (t5 - t4) / len(singles),
            "ms_per_percept": 1e3 * ((t1 - t0) + (t3 - t2)) / percepts,
            "vocabulary_fit_seconds": t2 - t1,
            "exact_nearest_share": float((extractor.nearest(x)[0] == exact).float().mean()),
            "keypoints_per_percept": float(np.mean([len(k) for k in detected])),
            "features_per_percept": float(presence.sum(1).float().mean()),
            "vocabulary_size": extractor.n_features,
            "features_seen": int(presence.any(0).sum()),
        }
    headline = next(iter(results.values()))
    summary = {
        "ms_per_percept": headline["ms_per_percept"],
        "features_per_percept": headline["features_per_percept"],
        "vocabulary_size": headline["vocabulary_size"],
        "percepts": percepts,
        "window": maze.window,
        "threads": SiftExtractor(threads=threads).threads,
        "variants": results,
    }
    write_summary(out, summary)
    names = list(results)
    width = max(len(n) for n in names) + 2
    print(f"{'figure':<36}" + "".join(f"{n:>{width}}" for n in names))
    for key in headline:
        print(f"{key:<36}" + "".join(f"{results[n][key]:>{width}.4g}" for n in names))
    print_table({"percepts": percepts, "window": maze.window, "written": str(out / "summary.json")})
    return summary
