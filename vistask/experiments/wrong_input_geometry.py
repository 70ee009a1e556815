"""Wrong inputs of ``scripts/sweep_wrong_inputs.py`` over the SE(3) densities, NBP, grasp
learning and patch extraction: values of another type, out of range, and numbers that break
kernel densities (non-finite or far particles, huge weights, products without overlap).

Example:
    >>> cases = [*density_cases(), *grasp_cases()]
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import torch

from vistask.experiments.wrong_inputs import Case, case, type_cases
from vistask.grasp import GraspLearner, Workspace, demonstration_density, empirical_density
from vistask.grasp.importance import Trials
from vistask.objects import NBP
from vistask.se3 import (
    R3S2KDE,
    SE3KDE,
    fit_density,
    identity_poses,
    mixture,
    product,
    random_poses,
)
from vistask.vision import PatchExtractor, Symmetry, intrinsics_from_fovy


def sample_poses(n: int = 5, seed: int = 0) -> torch.Tensor:
    """(n, 7) random poses of a seeded generator."""
    return random_poses(n, generator=torch.Generator().manual_seed(seed))


def sample_density() -> SE3KDE:
    """A density of five random particles."""
    return SE3KDE(sample_poses(), sigma_t=0.05, sigma_r=0.3)


def density_cases() -> Iterator[Case]:
    """Cases over the SE(3) densities and their bandwidths, products and mixtures."""
    points = sample_poses()
    yield from type_cases("SE3KDE", SE3KDE, points=points)
    yield from type_cases("density.sample", sample_density().sample, n=10)
    yield from type_cases("density.modes", sample_density().modes)
    yield from type_cases("density.evaluate", sample_density().evaluate, points=points)
    yield from type_cases("random_poses", random_poses, n=3)
    yield from type_cases("product", product, densities=[sample_density(), sample_density()], n=10)
    wrong_points = {
        "complex": lambda: points.to(torch.complex64),
        "float16": lambda: points.half(),
        "int": lambda: points.long(),
        "bool": lambda: points.bool(),
        "shape (5, 6)": lambda: points[:, :6],
        "shape (7,)": lambda: points[0],
        "a NaN": lambda: torch.where(torch.arange(7) == 0, math.nan, points),
        "an inf": lambda: torch.where(torch.arange(7) == 1, math.inf, points),
        "a particle at 1e200": lambda: torch.cat(
            [points.double(), torch.tensor([[1e200, 0, 0, 0, 0, 0, 1]], dtype=torch.float64)]
        ),
        "zero quaternion": lambda: torch.cat([points[:, :3], torch.zeros(5, 4)], 1),
        "no particles": lambda: points[:0],
        "a list of strings": lambda: [["a"] * 7],
    }
    for what, make in wrong_points.items():
        yield case("numbers", f"SE3KDE(points={what})", lambda m=make: SE3KDE(m()), "points")
        if what in ("shape (7,)", "no particles"):
            continue  # one pose, and none, are batches evaluate takes
        yield case(
            "numbers",
            f"density.evaluate({what})",
            lambda m=make: sample_density().evaluate(m()),
            "points",
        )
    weights = {
        "negative": torch.tensor([1.0, -1, 1, 1, 1]),
        "all zero": torch.zeros(5),
        "NaN": torch.tensor([1.0, math.nan, 1, 1, 1]),
        "inf": torch.tensor([1.0, math.inf, 1, 1, 1]),
        "wrong length": torch.ones(3),
        "complex": torch.ones(5, dtype=torch.complex64),
        "2-D": torch.ones(5, 1),
    }
    for what, w in weights.items():
        yield case("numbers", f"SE3KDE(weights={what})", lambda w=w: SE3KDE(points, w), "weights")
    for name, value in [
        ("sigma_t", 0.0),
        ("sigma_r", -0.1),
        ("sigma_t", math.inf),
        ("sigma_r", math.inf),
    ]:
        yield case(
            "ranges",
            f"SE3KDE({name}={value})",
            lambda n=name, v=value: SE3KDE(points, **{n: v}),
            name,
        )
    yield case(
        "ranges", "SE3KDE(kernel='cosine')", lambda: SE3KDE(points, kernel="cosine"), "kernel"
    )
    yield case("ranges", "SE3KDE(device='gpu')", lambda: SE3KDE(points, device="gpu"), "device")
    yield case("ranges", "R3S2KDE(points of 7 columns)", lambda: R3S2KDE(points), "points")
    for name, value in [("k", 0), ("n_starts", 0), ("n_iter", -1), ("k", -2)]:
        yield case(
            "ranges",
            f"density.modes({name}={value})",
            lambda n=name, v=value: sample_density().modes(**{n: v}),
            name,
        )
    yield case("ranges", "density.sample(-1)", lambda: sample_density().sample(-1), "n")
    yield case(
        "ranges",
        "density.evaluate(chunk_size=0)",
        lambda: sample_density().evaluate(points, chunk_size=0),
        "chunk_size",
    )
    yield case(
        "ranges",
        "density.evaluate(cutoff=-1)",
        lambda: sample_density().evaluate(points, cutoff=-1.0),
        "cutoff",
    )
    yield case("ranges", "random_poses(-1)", lambda: random_poses(-1), "n")
    yield case(
        "ranges",
        "random_poses(3, translation_scale=-1)",
        lambda: random_poses(3, translation_scale=-1.0),
        "translation_scale",
    )
    yield case("ranges", "identity_poses(-2)", lambda: identity_poses(-2), "batch")
    yield case("ranges", "product([])", lambda: product([], 10), "densities")
    yield case("ranges", "product([d, d], n=0)", lambda: product([sample_density()] * 2, 0), "n")
    yield case("ranges", "mixture([])", lambda: mixture([]), "densities")
    yield case(
        "numbers",
        "mixture(coefficients=[-1, 2])",
        lambda: mixture([sample_density()] * 2, [-1.0, 2.0]),
        "coefficients",
    )
    yield case(
        "numbers",
        "mixture(coefficients of another length)",
        lambda: mixture([sample_density()] * 2, [1.0]),
        "coefficients",
    )
    yield case(
        "types",
        "product([SE3KDE, R3S2KDE])",
        lambda: product([sample_density(), R3S2KDE.from_se3(sample_density())], 10),
        "densities",
    )
    yield Case(
        "numbers",
        "weights near 1e308 (float64)",
        lambda: _positive_at_particles(
            SE3KDE(points.double(), torch.full((5,), 1e308, dtype=torch.float64))
        ),
        result=True,
    )
    yield Case(
        "numbers",
        "float32 density at its particles, sigma_r 1e-4",
        lambda: _peaks_at_particles(SE3KDE(points, sigma_t=0.01, sigma_r=1e-4)),
        result=True,
    )
    far = SE3KDE(sample_poses() + torch.tensor([100.0, 0, 0, 0, 0, 0, 0]), sigma_t=0.01)
    yield case(
        "numbers",
        "product of two far-apart densities",
        lambda: product([sample_density(), far], 50),
        "overlap",
    )
    yield case(
        "ranges", "fit_density(method='best')", lambda: fit_density(points, method="best"), "method"
    )
    yield case("ranges", "fit_density(one particle)", lambda: fit_density(points[:1]), "points")


def _positive_at_particles(density: SE3KDE) -> None:
    """Raise ``ArithmeticError`` unless the density is finite and positive at its particles."""
    values = density.evaluate(density.points)
    if not bool(torch.isfinite(values).all() and (values > 0).all()):
        raise ArithmeticError(f"density values {values.tolist()}")


def _peaks_at_particles(density: SE3KDE) -> None:
    """Raise ``ArithmeticError`` unless far-apart particles' narrow kernels give each its
    weight at its own centre (to 1e-5)."""
    values = density.evaluate(density.points)
    if not torch.allclose(values, density.weights, rtol=1e-5, atol=0):
        raise ArithmeticError(f"values {values.tolist()} at the centres, not the weights")


def grasp_cases() -> Iterator[Case]:
    """Cases over grasp learning, NBP, patch extraction and camera intrinsics."""
    hypothesis = demonstration_density(identity_poses(2))
    yield from type_cases("GraspLearner", GraspLearner, hypothesis=hypothesis)
    yield from type_cases(
        "demonstration_density", demonstration_density, teacher_grasps=identity_poses(2)
    )
    yield from type_cases("NBP", NBP)
    yield from type_cases("PatchExtractor", PatchExtractor)
    for name, value in {
        "reliability": -1.0,
        "sigma_t": 0.0,
        "sigma_r": -1.0,
    }.items():
        yield case(
            "ranges",
            f"GraspLearner({name}={value})",
            lambda n=name, v=value: GraspLearner(hypothesis, **{n: v}),
            name,
        )
    for name, value in {"n_per_demo": 0, "noise_t": -0.01, "noise_r": -1.0, "sigma_t": 0.0}.items():
        yield case(
            "ranges",
            f"demonstration_density({name}={value})",
            lambda n=name, v=value: demonstration_density(identity_poses(2), **{n: v}),
            name,
        )
    yield case(
        "ranges",
        "demonstration_density(no grasps)",
        lambda: demonstration_density(identity_poses(0)),
        "teacher_grasps",
    )
    yield case(
        "ranges",
        "Workspace(reach=(0.9, 0.3))",
        lambda: Workspace(0.8, (0.0, 0.0, 0.9), reach=(0.9, 0.3)),
        "reach",
    )
    yield case(
        "ranges", "Workspace(floor_z=nan)", lambda: Workspace(math.nan, (0.0, 0.0, 0.9)), "floor_z"
    )
    yield case(
        "ranges",
        "Workspace(pregrasp_distance=-0.1)",
        lambda: Workspace(0.8, (0.0, 0.0, 0.9), pregrasp_distance=-0.1),
        "pregrasp_distance",
    )
    yield case("types", "Workspace(base=(0, 0))", lambda: Workspace(0.8, (0.0, 0.0)), "base")
    trials = Trials()
    trials.add(identity_poses(3), torch.tensor([True, False, True]), 0)
    yield case(
        "ranges",
        "empirical_density(c_rel=-1)",
        lambda: empirical_density(trials, [hypothesis], c_rel=-1.0),
        "c_rel",
    )
    yield case(
        "ranges",
        "Trials.add(3 grasps, 2 outcomes)",
        lambda: Trials().add(identity_poses(3), torch.tensor([True, False]), 0),
        "success",
    )
    for name, value in {
        "n_particles": 0,
        "sigma_t": -1.0,
        "floor": 1.5,
        "n_modes": 0,
        "refine_iters": -1,
        "cutoff": -1.0,
        "color_sigma": 0.0,
        "min_matches": -1,
    }.items():
        yield case("ranges", f"NBP({name}={value})", lambda n=name, v=value: NBP(**{n: v}), name)
    for name, value in {
        "spacing": 0,
        "blur_sigma": -1.0,
        "canny_low": -5.0,
        "max_depth": 0.0,
    }.items():
        yield case(
            "ranges",
            f"PatchExtractor({name}={value})",
            lambda n=name, v=value: PatchExtractor(**{n: v}),
            name,
        )
    yield case(
        "ranges",
        "Symmetry.about_axis(axis=(0, 0, 0))",
        lambda: Symmetry.about_axis((0.0, 0.0, 0.0)),
        "axis",
    )
    yield case(
        "ranges", "Symmetry.about_axis(order=0)", lambda: Symmetry.about_axis(order=0), "order"
    )
    yield case(
        "ranges",
        "intrinsics_from_fovy(0, 10, 10)",
        lambda: intrinsics_from_fovy(0.0, 10, 10),
        "fovy",
    )
    yield case(
        "ranges",
        "intrinsics_from_fovy(60, 0, 10)",
        lambda: intrinsics_from_fovy(60.0, 0, 10),
        "height",
    )
