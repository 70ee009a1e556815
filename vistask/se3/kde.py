"""Kernel density estimates on SE(3) (and, through the shared base, on R^3 x S^2).

A density is f(x) = sum_i w_i K(x; x_i) over weighted particles x_i = (t_i, u_i) with one
bandwidth pair (sigma_t, sigma_r); see ``vistask.se3`` for the conventions.

Imports go one way: ``r3s2`` (the R^3 x S^2 densities, projection of SE(3) densities) and
``bandwidth`` (bandwidth selection, ``fit_density``) build on this module, never the reverse.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import ClassVar, TypeVar, Union

import torch
import torch.nn.functional as F

from vistask.checks import check_at_least, check_device, checked
from vistask.saving import load_state, save_state
from vistask.se3 import kernels
from vistask.se3.grid import CellIndex
from vistask.se3.poses import check_poses

# Kernel blocks of about 2**17 floats (512 KB) stay in cache through the in-place chain and
# are large enough to amortise per-op overhead (measured best on the 2-core dev machine).
# A GPU has no such cache to fit and pays a launch per op: blocks of 2**24 (128 MB in float64).
BLOCK_ELEMENTS = 1 << 17
GPU_BLOCK_ELEMENTS = 1 << 24


def _block_elements(device: torch.device) -> int:
    return BLOCK_ELEMENTS if device.type == "cpu" else GPU_BLOCK_ELEMENTS


# Query groups smaller than the radius gather fewer far pairs, at more per-group overhead.
GROUP_SCALE = 1.0

D = TypeVar("D", bound="KernelDensity")
Weighting = Union["KernelDensity", Callable[[torch.Tensor], torch.Tensor]]


@checked
class KernelDensity:
    """Weighted particles (t_i, u_i), t_i in R^3, u_i a unit vector with u ~ -u, shared bandwidth.

    Subclasses fix the direction space (unit quaternions for SE(3), axial directions on S^2).

    Args:
        points: (N, 3 + D) particles [t, u].
        weights: (N,) non-negative weights (normalised internally), or None for uniform.
        sigma_t: position bandwidth (Gaussian std; the triangular kernel reaches 2 sigma_t).
        sigma_r: orientation bandwidth in radians (the kernel is about exp(-angle^2 / sigma_r^2)).
        kernel: position kernel, "gaussian" or "triangular".
        device: device for the particles (default: that of ``points``).
    """

    dir_dim: ClassVar[int]
    point_name: ClassVar[str]

    def __init__(
        self,
        points: torch.Tensor,
        weights: torch.Tensor | None = None,
        sigma_t: float = 0.01,
        sigma_r: float = 0.3,
        kernel: str = "gaussian",
        device: torch.device | str | None = None,
    ) -> None:
        points = self.check_points(points, "points", batched=True)
        if device is not None:
            points = points.to(check_device(device))
        if points.shape[0] == 0:
            raise ValueError("points must hold at least one particle, got none")
        self.sigma_t, self.sigma_r = kernels.check_bandwidth(sigma_t, sigma_r)
        kernels.check_spread(points[:, :3], self.sigma_t)
        self.kernel = kernels.check_kernel(kernel)
        self.kappa = self.kappa_from_sigma(self.sigma_r)
        self._points = points
        self._weights = kernels.normalise_weights(weights, points)
        self._terms: kernels.PairTerms | None = None
        self._grids: dict[float, tuple[CellIndex, torch.Tensor, torch.Tensor, torch.Tensor]] = {}
        self.last_evaluated_pairs: int | None = None

    # --- space-specific hooks -------------------------------------------------------------
    @classmethod
    def check_points(cls, points: torch.Tensor, name: str, batched: bool = False) -> torch.Tensor:
        """Validate (..., 3 + D) points and renormalise their direction part."""
        raise NotImplementedError

    @staticmethod
    def kappa_from_sigma(sigma_r: float) -> float:
        """The direction kernel's concentration for the bandwidth ``sigma_r`` (radians)."""
        raise NotImplementedError

    @staticmethod
    def log_direction_normalizer(kappa: float) -> float:
        """Log of the direction kernel's normalising constant at ``kappa``."""
        raise NotImplementedError

    @staticmethod
    def direction_angle(u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        """Angle between directions (..., D) x (..., D) -> (...), with u ~ -u."""
        raise NotImplementedError

    # --- basic properties -----------------------------------------------------------------
    @property
    def points(self) -> torch.Tensor:
        """(N, 3 + D) particles."""
        return self._points

    @property
    def weights(self) -> torch.Tensor:
        """(N,) normalised weights."""
        return self._weights

    @property
    def device(self) -> torch.device:
        """The device its tensors are on."""
        return self._points.device

    def __len__(self) -> int:
        return self._points.shape[0]

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(n={len(self)}, sigma_t={self.sigma_t:g}, "
            f"sigma_r={self.sigma_r:g}, kernel={self.kernel!r}, device={self.device})"
        )

    def effective_sample_size(self) -> float:
        """Kish's effective sample size 1 / sum w_i^2 of the normalised weights."""
        return float(1.0 / (self._weights.double() ** 2).sum())

    def log_normalizer(self) -> float:
        """Log of the integral of one kernel over R^3 x (direction space)."""
        return kernels.log_position_normalizer(
            self.sigma_t, self.kernel
        ) + self.log_direction_normalizer(self.kappa)

    def _new(self: D, points: torch.Tensor, weights: torch.Tensor | None, **overrides) -> D:
        params = {"sigma_t": self.sigma_t, "sigma_r": self.sigma_r, "kernel": self.kernel}
        params.update({k: v for k, v in overrides.items() if v is not None})
        return type(self)(points, weights, **params)

    # --- evaluation -------------------------------------------------------------------------
    def _pair_terms(self) -> kernels.PairTerms:
        if self._terms is None:
            t, u = self._points[:, :3], self._points[:, 3:]
            self._terms = kernels.PairTerms(
                t, u, self._weights, self.sigma_t, self.kappa, self.kernel
            )
        return self._terms

    def _queries(self, points: torch.Tensor) -> tuple[torch.Tensor, tuple[int, ...]]:
        x = self.check_points(points, "query points")
        x = x.to(device=self.device, dtype=self._points.dtype)
        return x.reshape(-1, x.shape[-1]), tuple(x.shape[:-1])

    def evaluate(
        self,
        points: torch.Tensor,
        normalized: bool = False,
        chunk_size: int | None = None,
        cutoff: float | None = None,
    ) -> torch.Tensor:
        """Density at query points, f(x) = sum_i w_i K(x; x_i).

        Args:
            points: (..., 3 + D) query points.
            normalized: divide by the kernel's integral so that f integrates to 1 over
                R^3 x (direction space) (SO(3) has volume pi^2 under the quaternion metric,
                S^2 / {v ~ -v} area 2 pi). Unnormalised kernels peak at 1.
            chunk_size: queries per block (default: blocks of about 2**17 kernel values).
            cutoff: ignore particles farther than ``cutoff * sigma_t`` in position and use a grid
                neighbour search so only nearby pairs are evaluated (a Gaussian pair truncated
                weighs at most exp(-cutoff^2 / 2) of a kernel's peak: 3e-4 at 4, below
                float32's smallest normal number from 13). None evaluates every pair.

        Returns:
            (...) density values.
        """
        x, batch = self._queries(points)
        if cutoff is not None and not (math.isfinite(cutoff) and cutoff > 0):
            raise ValueError(f"cutoff must be a positive number of sigma_t, got {cutoff}")
        if chunk_size is not None and chunk_size < 1:
            raise ValueError(f"chunk_size must be >= 1, got {chunk_size}")
        if cutoff is None:
            values = self._evaluate_dense(x, chunk_size)
        else:
            values = self._evaluate_cutoff(x, chunk_size, cutoff)
        if normalized:
            values = values * math.exp(-self.log_normalizer())
        return values.reshape(batch)

    def __call__(self, points: torch.Tensor, **kwargs) -> torch.Tensor:
        """``evaluate(points, **kwargs)``: (M,) density values."""
        return self.evaluate(points, **kwargs)

    def _evaluate_dense(self, x: torch.Tensor, chunk_size: int | None) -> torch.Tensor:
        terms = self._pair_terms()
        feats, dirs = terms.query_features(x[:, :3], x[:, 3:])
        n = len(self)
        chunk = chunk_size or max(1, _block_elements(x.device) // n)
        chunk = min(chunk, max(1, x.shape[0]))
        out = torch.empty(x.shape[0], dtype=x.dtype, device=x.device)
        buf = torch.empty(2, chunk * n, dtype=x.dtype, device=x.device)
        for a in range(0, x.shape[0], chunk):
            b = min(a + chunk, x.shape[0])
            block = kernels.kernel_block(
                feats[a:b], dirs[a:b], terms.features, terms.u, terms, None, buf[0], buf[1]
            )
            torch.mv(block, terms.weights, out=out[a:b])
        return out

    def _grid(self, radius: float) -> tuple[CellIndex, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Cell index for a cut-off radius, with particle features in cell-sorted order."""
        if radius not in self._grids:
            terms = self._pair_terms()
            grid = CellIndex(terms.t, radius)
            perm = grid.perm
            self._grids[radius] = (
                grid,
                terms.features[perm].contiguous(),
                terms.u[perm].contiguous(),
                terms.weights[perm].contiguous(),
            )
        return self._grids[radius]

    def _evaluate_cutoff(self, x: torch.Tensor, chunk_size: int | None, cutoff: float):
        terms = self._pair_terms()
        support = cutoff if self.kernel == "gaussian" else min(cutoff, 2.0)
        radius = support * self.sigma_t
        grid, p_feats, p_dirs, p_weights = self._grid(radius)
        feats, dirs = terms.query_features(x[:, :3], x[:, 3:])
        tq = x[:, :3] - terms.center
        # Group queries by cells of GROUP_SCALE * radius: each group shares one neighbour gather.
        cells = torch.floor((tq - grid.origin) / (GROUP_SCALE * radius)).long()
        cells = cells - cells.min(dim=0).values
        dims = (cells.max(dim=0).values + 1).tolist()
        keys = (cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2]
        order = torch.argsort(keys)
        counts = torch.unique_consecutive(keys[order], return_counts=True)[1]
        group = torch.repeat_interleave(torch.arange(counts.numel(), device=x.device), counts)
        tq_sorted = tq[order]
        index = group[:, None].expand(-1, 3)
        inf = torch.full((counts.numel(), 3), math.inf, dtype=x.dtype, device=x.device)
        box_min = inf.scatter_reduce(0, index, tq_sorted, "amin").tolist()
        box_max = (-inf).scatter_reduce(0, index, tq_sorted, "amax").tolist()
        feats, dirs = feats[order], dirs[order]
        out = torch.zeros(x.shape[0], dtype=x.dtype, device=x.device)
        block_elements = _block_elements(x.device)
        buf = torch.empty(2, BLOCK_ELEMENTS, dtype=x.dtype, device=x.device)  # grown as needed
        start, pairs = 0, 0
        for g, size in enumerate(counts.tolist()):
            stop, a0 = start + size, start
            start = stop
            idx = grid.neighbours(box_min[g], box_max[g])
            m = idx.numel()
            if m == 0:
                continue
            pairs += size * m
            g_feats, g_dirs, g_weights = p_feats[idx], p_dirs[idx], p_weights[idx]
            chunk = chunk_size or max(1, block_elements // m)
            if buf.shape[1] < min(chunk, size) * m:
                buf = torch.empty(2, min(chunk, size) * m, dtype=x.dtype, device=x.device)
            for a in range(a0, stop, chunk):
                b = min(a + chunk, stop)
                block = kernels.kernel_block(
                    feats[a:b], dirs[a:b], g_feats, g_dirs, terms, cutoff, buf[0], buf[1]
                )
                torch.mv(block, g_weights, out=out[a:b])
        # Kept for benchmarks: how many kernel pairs the neighbour search left to evaluate.
        self.last_evaluated_pairs = pairs
        result = torch.empty_like(out)
        result[order] = out
        return result

    def kernel_matrix(self, points: torch.Tensor, cutoff: float | None = None) -> torch.Tensor:
        """Unnormalised kernel values K(x_q; x_i) for (Q, 3 + D) queries -> (Q, N), unweighted."""
        if cutoff is not None and not (math.isfinite(cutoff) and cutoff > 0):
            raise ValueError(f"cutoff must be a positive number of sigma_t, got {cutoff}")
        x, _ = self._queries(points)
        terms = self._pair_terms()
        feats, dirs = terms.query_features(x[:, :3], x[:, 3:])
        buf = torch.empty(2, x.shape[0] * len(self), dtype=x.dtype, device=x.device)
        return kernels.kernel_block(feats, dirs, terms.features, terms.u, terms, cutoff, *buf)

    # --- sampling and reweighting -----------------------------------------------------------
    def sample(self, n: int, generator: torch.Generator | None = None) -> torch.Tensor:
        """Draw n points: systematic resampling of particles, then one draw per kernel.

        Args:
            n: number of samples.
            generator: torch random generator on the density's device.

        Returns:
            (n, 3 + D) samples in random order.
        """
        if n < 0:
            raise ValueError(f"n must be non-negative, got {n}")
        idx = kernels.systematic_resample(self._weights, n, generator)
        idx = idx[torch.randperm(n, generator=generator, device=self.device)]
        centers = self._points[idx]
        t = centers[:, :3] + kernels.sample_position_offsets(
            n, self.sigma_t, self.kernel, generator, dtype=centers.dtype, device=self.device
        )
        u = kernels.sample_axial_vmf(centers[:, 3:], self.kappa, generator)
        return torch.cat([t, u], dim=1)

    def reweight(self: D, fn: Weighting, proposal: Weighting | None = None) -> D:
        """Importance reweighting: new weights ∝ w_i fn(x_i) [/ proposal(x_i)].

        Args:
            fn: a density (its ``evaluate``) or a callable (N, 3 + D) -> (N,) of non-negative
                values.
            proposal: optional density or callable the particles were drawn from; the weights
                are divided by it (classic importance weights target / proposal).

        Returns:
            a new density with the same particles and bandwidth.
        """
        factor = _apply_weighting(fn, self._points, "fn")
        if proposal is not None:
            at = _apply_weighting(proposal, self._points, "proposal")
            if not (at > 0).all():
                raise ValueError("proposal must be > 0 at every particle (it drew them)")
            factor = factor / at
        if not (self._weights * factor > 0).any():
            raise ValueError("fn is 0 at every particle of positive weight: nothing is left")
        return self._new(self._points, self._weights * factor)

    # --- moments and modes ------------------------------------------------------------------
    def mean(self) -> torch.Tensor:
        """(3 + D,) weighted mean position and mean axis (top eigenvector of sum w u u^T)."""
        t = self._weights @ self._points[:, :3]
        return torch.cat([t, kernels.principal_axis(self._points[:, 3:], self._weights)])

    def moments(self) -> dict[str, torch.Tensor]:
        """Mean (3 + D,), position covariance (3, 3) and direction scatter sum w u u^T (D, D)."""
        t, u, w = self._points[:, :3], self._points[:, 3:], self._weights
        mean_t = w @ t
        centred = t - mean_t
        return {
            "mean": self.mean(),
            "position_covariance": (centred * w[:, None]).T @ centred,
            "direction_scatter": (u * w[:, None]).T @ u,
        }

    def modes(
        self,
        k: int = 1,
        n_starts: int = 32,
        n_iter: int = 20,
        generator: torch.Generator | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Modes by mean shift from resampled particles.

        Args:
            k: number of distinct modes to return (fewer when fewer are found).
            n_starts: mean-shift starting points (systematically resampled particles).
            n_iter: mean-shift iterations.
            generator: random generator for picking candidate starts.

        Returns:
            (k', 3 + D) modes sorted by decreasing density, (k',) unnormalised densities there.
        """
        check_at_least(1, k=k, n_starts=n_starts, n_iter=n_iter)
        # Resampled starts visit every region in proportion to its mass, so minor modes get some.
        picked = kernels.systematic_resample(self._weights, min(n_starts, len(self)), generator)
        x = self._points[torch.unique(picked)]
        u_part = self._points[:, 3:]
        for _ in range(n_iter):
            kw = self.kernel_matrix(x) * self._weights
            total = kw.sum(dim=1, keepdim=True)
            if not (total > 0).all():
                break
            t = (kw @ self._points[:, :3]) / total
            signed = kw * torch.sign(x[:, 3:] @ u_part.T)
            u = F.normalize(signed @ u_part, dim=1)
            x = torch.cat([t, u], dim=1)
        values = self.evaluate(x)
        order = torch.argsort(values, descending=True)
        kept: list[int] = []
        for i in order.tolist():
            far = all(
                (x[i, :3] - x[j, :3]).norm() > 0.5 * self.sigma_t
                or self.direction_angle(x[i, 3:], x[j, 3:]) > 0.5 * self.sigma_r
                for j in kept
            )
            if far:
                kept.append(i)
            if len(kept) == k:
                break
        return x[kept], values[kept]

    def mode(self, **kwargs) -> torch.Tensor:
        """(3 + D,) the highest mode found by ``modes``."""
        return self.modes(k=1, **kwargs)[0][0]

    # --- persistence and devices ------------------------------------------------------------
    def state_dict(self) -> dict:
        """Its settings and learned values as plain values and tensors (for ``save``)."""
        return {
            "type": type(self).__name__,
            "points": self._points.cpu(),
            "weights": self._weights.cpu(),
            "sigma_t": self.sigma_t,
            "sigma_r": self.sigma_r,
            "kernel": self.kernel,
        }

    def save(self, path: str | Path) -> None:
        """Save particles, weights and bandwidth (``vistask.saving``: atomic, checked on load)."""
        save_state(path, type(self).__name__, self.state_dict())

    @classmethod
    def load(cls: type[D], path: str | Path, device: torch.device | str | None = None) -> D:
        """Load a density written by ``save``."""
        return cls.from_state_dict(load_state(path, cls.__name__), device)

    @classmethod
    def from_state_dict(cls: type[D], state: dict, device: torch.device | str | None = None) -> D:
        """Rebuild a density from ``state_dict()``, bit for bit: the saved particles and
        weights were normalised when the density was made, and normalising them again could
        move their last bits."""
        density = cls(
            state["points"],
            state["weights"],
            sigma_t=state["sigma_t"],
            sigma_r=state["sigma_r"],
            kernel=state["kernel"],
            device=device,
        )
        density._points = state["points"].to(density.device)
        density._weights = state["weights"].to(density.device)
        return density

    def to(self: D, device: torch.device | str) -> D:
        """A copy of the density on ``device``."""
        device = check_device(device)
        return self._new(self._points.to(device), self._weights.to(device))


def _apply_weighting(fn: Weighting, points: torch.Tensor, name: str) -> torch.Tensor:
    if not (isinstance(fn, KernelDensity) or callable(fn)):
        raise TypeError(f"{name} must be a density or a function of the points, got {fn!r}")
    values = fn.evaluate(points) if isinstance(fn, KernelDensity) else fn(points)
    values = torch.as_tensor(values, dtype=points.dtype, device=points.device)
    if values.shape != points.shape[:1]:
        got = tuple(values.shape)
        raise ValueError(f"{name} must return shape ({points.shape[0]},), got {got}")
    if not (torch.isfinite(values).all() and (values >= 0).all()):
        raise ValueError(f"{name} must return finite values >= 0 at every particle")
    return values


@checked
def product(
    densities: Sequence[D],
    n: int,
    generator: torch.Generator | None = None,
    sigma_t: float | None = None,
    sigma_r: float | None = None,
) -> D:
    """Product of densities by importance sampling.

    Draws n points from the first density and weights each by the values of the others there
    (the weights are then target / proposal up to a constant).

    Args:
        densities: densities of the same type (one: its particles resampled).
        n: number of particles of the result.
        generator: random generator.
        sigma_t, sigma_r: bandwidth of the result (default: the first density's).

    Returns:
        a density with n particles.
    """
    first = _check_densities(densities)
    check_at_least(1, n=n)
    x = first.sample(n, generator)
    # Summed in log space: a product of many small values would underflow where none does.
    log_weights = torch.zeros(n, dtype=torch.float64, device=x.device)
    for k, other in enumerate(densities[1:], 1):
        values = other.evaluate(x.to(other.device))
        # Kernel values stop at a floor (see kernels.WEIGHT_HEADROOM): all there, no overlap.
        if not (values > 2 * math.exp(kernels.log_floor(values.dtype))).any():
            raise ValueError(
                f"densities do not overlap: densities[{k}] is nil (below float precision) at "
                f"all {n} particles drawn from densities[0]"
            )
        log_weights += values.to(x.device, torch.float64).log()
    weights = (log_weights - log_weights.max()).exp()
    return first._new(x, weights, sigma_t=sigma_t, sigma_r=sigma_r)


def _check_densities(densities: Sequence[D]) -> D:
    """The first of one or more densities of one type; a clear error otherwise."""
    if isinstance(densities, KernelDensity) or not isinstance(densities, Sequence):
        raise TypeError(f"densities must be a list of densities, got {type(densities).__name__}")
    if len(densities) < 1:
        raise ValueError("densities must hold at least one density, got none")
    first = densities[0]
    for d in densities:
        if not isinstance(d, KernelDensity) or type(d) is not type(first):
            kinds = sorted({type(d).__name__ for d in densities})
            raise TypeError(f"densities must be of one type, got {kinds}")
    return first


@checked
def mixture(
    densities: Sequence[D], coefficients: Sequence[float] | torch.Tensor | None = None
) -> D:
    """Mixture sum_k c_k f_k of densities with a common bandwidth and kernel.

    Args:
        densities: densities of the same type, bandwidth and kernel.
        coefficients: (K,) non-negative mixture coefficients (normalised), default uniform.

    Returns:
        a density holding all particles.
    """
    first = _check_densities(densities)
    for d in densities:
        if (d.sigma_t, d.sigma_r, d.kernel) != (first.sigma_t, first.sigma_r, first.kernel):
            raise ValueError("densities of a mixture must share their bandwidth and kernel")
    try:
        coef = torch.ones(len(densities)) if coefficients is None else torch.as_tensor(coefficients)
    except (TypeError, ValueError, RuntimeError):
        raise TypeError(f"coefficients must be numbers, got {coefficients!r}") from None
    if coef.shape != (len(densities),) or coef.is_complex():
        raise ValueError(f"coefficients must be {len(densities)} real numbers, got {coefficients}")
    if not (torch.isfinite(coef).all() and (coef >= 0).all() and (coef > 0).any()):
        raise ValueError(f"coefficients must be finite, >= 0, not all 0, got {coefficients}")
    coef = coef.to(dtype=first.points.dtype, device=first.device)
    points = torch.cat([d.points.to(first.device) for d in densities])
    weights = torch.cat(
        [c * d.weights.to(first.device) for c, d in zip(coef, densities, strict=True)]
    )
    return first._new(points, weights)


@checked
class SE3KDE(KernelDensity):
    """Kernel density on SE(3): particles are (N, 7) poses [t, qx, qy, qz, qw].

    Kernel: position (Gaussian, or triangular with support 2 sigma_t) times
    ``exp(kappa (|q . q_i| - 1))`` with kappa = 1 / (1 - cos(sigma_r / 2)) (nuklei).
    See ``KernelDensity`` for the arguments.
    """

    dir_dim = 4
    point_name = "poses"

    @classmethod
    def check_points(cls, points: torch.Tensor, name: str, batched: bool = False) -> torch.Tensor:
        """Validate (..., 3 + D) points and renormalise their direction part."""
        return check_poses(points, name, batched=batched)

    @staticmethod
    def kappa_from_sigma(sigma_r: float) -> float:
        """The direction kernel's concentration for the bandwidth ``sigma_r`` (radians)."""
        return kernels.quaternion_kappa(sigma_r)

    @staticmethod
    def log_direction_normalizer(kappa: float) -> float:
        """Log of the direction kernel's normalising constant at ``kappa``."""
        return kernels.log_quaternion_normalizer(kappa)

    @staticmethod
    def direction_angle(u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        """Angle between directions (..., D) x (..., D) -> (...), with u ~ -u."""
        return 2.0 * torch.acos((u * v).sum(-1).abs().clamp(max=1.0))
