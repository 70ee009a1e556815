"""Kernel pieces shared by the SE(3) and R^3 x S^2 densities.

A kernel is a position part times a direction part. Directions are unit vectors u in R^D
(D = 4: quaternions, D = 3: axial edge directions) identified with -u, and the direction part
is exp(kappa (|u . u_i| - 1)), the von Mises-Fisher form folded onto the half-sphere.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from scipy import special

KERNELS = ("gaussian", "triangular")

# Denormal floats are ~30x slower to compute with on CPU, and kernel values that small are
# meaningless next to the kernel's peak of 1: exponents are clamped so that kernel values stay
# this factor above the dtype's smallest normal number, and their products with particle
# weights down to its inverse stay normal too (in float32, exp(-60): with exp(-87) the values
# are normal but not their products, and a mean-shift step over 2000 particles runs 80 times
# slower).
WEIGHT_HEADROOM = 1e12


def log_floor(dtype: torch.dtype) -> float:
    """The smallest kernel exponent computed in ``dtype`` (``WEIGHT_HEADROOM``)."""
    return math.log(torch.finfo(dtype).tiny * WEIGHT_HEADROOM)


def floored_exp_(exponents: torch.Tensor) -> torch.Tensor:
    """exp() of kernel exponents in place, each first raised to ``log_floor`` of its dtype."""
    return exponents.clamp_(min=log_floor(exponents.dtype)).exp_()


# Narrowest bandwidths a kernel can hold: a float32 pose resolves about 1e-7 m at 1 m and
# 1e-7 rad, and the float64 terms below keep a kernel's exponent to 1e-6 down to these.
SIGMA_T_MIN = 1e-5  # metres
SIGMA_T_MAX = 1e6  # metres: wider, a unit mistake (and squares overflow)
SIGMA_R_MIN = 1e-5  # radians
# Largest error allowed in a kernel's exponent (a relative error of the kernel value): a term
# whose float32 cancellation error would exceed it is computed in float64.
EXPONENT_TOLERANCE = 1e-6
_EPS32 = float(torch.finfo(torch.float32).eps)
_EPS64 = float(torch.finfo(torch.float64).eps)
# Beyond this error of a kernel exponent even in float64 (0.1% of a kernel value), a density
# is refused rather than computed wrong (``check_spread``).
REFUSED_EXPONENT_ERROR = 1e-3


def check_bandwidth(
    sigma_t: float, sigma_r: float, names: tuple[str, str] = ("sigma_t", "sigma_r")
) -> tuple[float, float]:
    """Validate the position and orientation bandwidths (called ``names`` in errors) and
    return them as floats."""
    sigma_t, sigma_r = float(sigma_t), float(sigma_r)
    if not (math.isfinite(sigma_t) and SIGMA_T_MIN <= sigma_t <= SIGMA_T_MAX):
        raise ValueError(
            f"{names[0]} must be in [{SIGMA_T_MIN}, {SIGMA_T_MAX:g}] metres (narrower kernels "
            f"are below what float precision holds), got {sigma_t}"
        )
    if not (math.isfinite(sigma_r) and SIGMA_R_MIN <= sigma_r <= 2 * math.pi):
        raise ValueError(
            f"{names[1]} must be in [{SIGMA_R_MIN}, 2 pi] radians (narrower kernels are below "
            f"what float precision holds), got {sigma_r}"
        )
    return sigma_t, sigma_r


def check_kernel(kernel: str) -> str:
    """The kernel name, if it is "gaussian" or "triangular"; a ``ValueError`` otherwise."""
    if kernel not in KERNELS:
        raise ValueError(f"kernel must be one of {KERNELS}, got {kernel!r}")
    return kernel


def quaternion_kappa(sigma_r: float) -> float:
    """Concentration for a rotation bandwidth (nuklei): kappa = 1 / (1 - cos(sigma_r / 2)).

    Since q . q_i = cos(theta / 2) for a rotation angle theta, the kernel is about
    exp(-theta^2 / sigma_r^2) for small angles. 1 - cos x is computed as 2 sin^2(x / 2), which
    keeps its digits for small bandwidths.
    """
    return 0.5 / math.sin(sigma_r / 4.0) ** 2


def direction_kappa(sigma_r: float) -> float:
    """Concentration for an axial direction bandwidth on S^2: kappa = 1 / (1 - cos(sigma_r)).

    v . v_i = cos(theta) for the angle theta between the directions, so the kernel is about
    exp(-theta^2 / sigma_r^2) for small angles, matching the quaternion convention.
    """
    return 0.5 / math.sin(sigma_r / 2.0) ** 2


def log_quaternion_normalizer(kappa: float) -> float:
    """Log of the integral of exp(kappa (|q . mu| - 1)) over SO(3) = S^3 / {q ~ -q}.

    With t = q . mu = cos(a), the S^3 volume element is 4 pi sin^2(a) da, and over the half
    sphere int_0^{pi/2} exp(kappa cos a) sin^2 a da = pi / (2 kappa) (I_1(kappa) + L_1(kappa))
    (I: modified Bessel, L: modified Struve), so the integral is
    2 pi^2 / kappa * exp(-kappa) (I_1 + L_1). For kappa > 50, exp(-kappa) (L_1 - I_1) is below
    1e-21 and the Bessel term alone (scaled, no overflow) is exact to float precision.
    """
    scaled_bessel = special.ive(1, kappa)
    if kappa > 50.0:
        scaled_struve = scaled_bessel
    else:
        scaled_struve = math.exp(-kappa) * special.modstruve(1, kappa)
    return math.log(2.0 * math.pi**2 / kappa) + math.log(scaled_bessel + scaled_struve)


def log_direction_normalizer(kappa: float) -> float:
    """Log of the integral of exp(kappa (|v . mu| - 1)) over S^2 / {v ~ -v} (area 2 pi).

    With t = v . mu uniform under the area measure, the integral is 2 pi (1 - e^-kappa) / kappa.
    """
    return math.log(2.0 * math.pi) + math.log(-math.expm1(-kappa)) - math.log(kappa)


def log_position_normalizer(sigma_t: float, kernel: str) -> float:
    """Log of the integral over R^3 of the position kernel (Gaussian or triangular)."""
    if kernel == "gaussian":
        return 1.5 * math.log(2.0 * math.pi * sigma_t**2)
    # max(0, 1 - r / h) with h = 2 sigma_t integrates to pi h^3 / 3 over R^3.
    return math.log(math.pi * (2.0 * sigma_t) ** 3 / 3.0)


def normalise_weights(weights: torch.Tensor | None, points: torch.Tensor) -> torch.Tensor:
    """(N,) particle weights checked and scaled to sum 1 (uniform when None) for (N, .) points."""
    n = points.shape[0]
    if weights is None:
        return torch.full((n,), 1.0 / n, dtype=points.dtype, device=points.device)
    if not isinstance(weights, torch.Tensor):
        weights = torch.as_tensor(weights)
    if weights.shape != (n,):
        raise ValueError(f"weights must have shape ({n},), got {tuple(weights.shape)}")
    if weights.is_complex() or weights.dtype == torch.bool:
        raise TypeError(f"weights must be real numbers, got {weights.dtype}")
    if not torch.isfinite(weights).all() or (weights < 0).any():
        raise ValueError(f"weights must be finite and non-negative, got {weights.tolist()[:8]}")
    peak = weights.max()
    if not peak > 0:
        raise ValueError("weights must not all be zero")
    # Scaled by the largest first: a sum of weights near the dtype's maximum would overflow.
    weights = (weights / peak).to(dtype=points.dtype, device=points.device)
    return weights / weights.sum()


def principal_axis(u: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """Top eigenvector of sum_i w_i u_i u_i^T: the sign-invariant mean axis, last entry >= 0."""
    scatter = (u * weights[:, None]).T @ u
    axis = torch.linalg.eigh(scatter.double())[1][:, -1].to(u.dtype)
    return axis if axis[-1] >= 0 else -axis


def sample_axial_vmf(
    mu: torch.Tensor, kappa: float, generator: torch.Generator | None = None
) -> torch.Tensor:
    """One draw per row from the density proportional to exp(kappa |u . mu|) on S^{D-1}.

    Wood's (1994) rejection sampler for the component w = u . mu of a von Mises-Fisher draw,
    restricted to w >= 0 (which makes it exactly the folded kernel rather than the cosh mixture of
    vMF(mu) and vMF(-mu)), a uniform tangent direction, and a random overall sign (u ~ -u).

    Args:
        mu: (n, D) unit mean directions, D >= 3.
        kappa: concentration > 0.
        generator: torch random generator on mu's device.

    Returns:
        (n, D) unit vectors.
    """
    n, dim = mu.shape
    device, dtype = mu.device, torch.float64
    m1 = dim - 1.0
    # Numerically stable form of b = (-2 kappa + sqrt(4 kappa^2 + m1^2)) / m1.
    b = m1 / (2.0 * kappa + math.sqrt(4.0 * kappa**2 + m1**2))
    x0 = (1.0 - b) / (1.0 + b)
    c = kappa * x0 + m1 * math.log(1.0 - x0**2)
    w = torch.empty(n, dtype=dtype, device=device)
    pending = torch.arange(n, device=device)
    for _ in range(1000):
        k = pending.numel()
        if k == 0:
            break
        # Beta(m1/2, m1/2) as (1 + x) / 2 with x a coordinate of a uniform point on S^{D-1}.
        g = torch.randn(k, dim, dtype=dtype, device=device, generator=generator)
        z = 0.5 * (1.0 + g[:, 0] / g.norm(dim=1))
        cand = (1.0 - (1.0 + b) * z) / (1.0 - (1.0 - b) * z)
        log_u = torch.rand(k, dtype=dtype, device=device, generator=generator).log()
        accept = (kappa * cand + m1 * torch.log1p(-x0 * cand) - c >= log_u) & (cand >= 0)
        w[pending[accept]] = cand[accept]
        pending = pending[~accept]
    else:
        raise RuntimeError("Wood's sampler did not converge")
    mu64 = mu.to(dtype)
    v = torch.randn(n, dim, dtype=dtype, device=device, generator=generator)
    v = F.normalize(v - (v * mu64).sum(1, keepdim=True) * mu64, dim=1)
    u = w[:, None] * mu64 + torch.sqrt((1.0 - w * w).clamp(min=0.0))[:, None] * v
    sign = torch.randint(0, 2, (n, 1), device=device, generator=generator, dtype=dtype) * 2 - 1
    return (sign * u).to(mu.dtype)


def sample_position_offsets(
    n: int,
    sigma_t: float,
    kernel: str,
    generator: torch.Generator | None = None,
    dtype: torch.dtype = torch.float32,
    device=None,
) -> torch.Tensor:
    """(n, 3) draws from the centred position kernel (Gaussian or triangular)."""
    if kernel == "gaussian":
        return sigma_t * torch.randn(n, 3, generator=generator, dtype=dtype, device=device)
    # Radius density ∝ r^2 (1 - r / h) on [0, h]: r / h ~ Beta(3, 2), the 3rd of 4 sorted uniforms.
    radius = torch.rand(n, 4, generator=generator, dtype=dtype, device=device).sort(dim=1).values
    radius = 2.0 * sigma_t * radius[:, 2:3]
    direction = torch.randn(n, 3, generator=generator, dtype=dtype, device=device)
    return radius * F.normalize(direction, dim=1)


def systematic_resample(
    weights: torch.Tensor, n: int, generator: torch.Generator | None = None
) -> torch.Tensor:
    """Systematic resampling: (N,) normalised weights -> (n,) particle indices."""
    cumulative = torch.cumsum(weights.to(torch.float64), dim=0)
    cumulative = cumulative / cumulative[-1]
    offset = torch.rand((), generator=generator, dtype=torch.float64, device=weights.device)
    positions = (torch.arange(n, dtype=torch.float64, device=weights.device) + offset) / n
    idx = torch.searchsorted(cumulative, positions, right=True)
    return idx.clamp(max=weights.numel() - 1)


def check_spread(t: torch.Tensor, sigma_t: float) -> None:
    """Raise ``ValueError`` unless (N, 3) translations lie close enough to their mean, in units
    of ``sigma_t``, for ``PairTerms``' expanded squared distances to hold their kernel
    exponents to ``REFUSED_EXPONENT_ERROR`` in float64."""
    if not t.numel():
        return
    t = t.double()
    spread = float((t - t.mean(dim=0)).norm(dim=1).max())
    if _EPS64 * (spread / sigma_t) ** 2 * 4.0 > REFUSED_EXPONENT_ERROR:
        raise ValueError(
            f"points spread {spread:.3g} m about their mean: at sigma_t {sigma_t:g} m, kernel "
            f"values that far apart are beyond float64's precision (use a wider sigma_t, or "
            f"densities of nearby particles)"
        )


class PairTerms:
    """Particle-side terms of a kernel, shared by every query block.

    For the Gaussian kernel the log position term -|t - t_i|^2 / (2 s^2) is one matmul of
    (Q, 5) query features [t / s^2, -|t|^2 / (2 s^2), 1] with (N, 5) particle features
    [t_i, 1, -|t_i|^2 / (2 s^2)]; for the triangular kernel the same matmul gives
    |t - t_i|^2. The direction term kappa (|u . u_i| - 1) comes from a second matmul. No
    (Q, N, D) intermediate is ever formed; the (Q, N) block is combined in place.

    Both expanded forms cancel large terms: in float32 the position term loses about
    eps (R / s)^2 (R: the particles' spread about their mean, on which translations are
    centred) and the direction term about eps kappa. Each term whose loss would exceed
    ``EXPONENT_TOLERANCE`` is computed in float64 (``position_dtype``, ``direction_dtype``),
    so a float32 density keeps its precision for every bandwidth it accepts.
    """

    def __init__(
        self,
        t: torch.Tensor,
        u: torch.Tensor,
        weights: torch.Tensor,
        sigma_t: float,
        kappa: float,
        kernel: str,
    ) -> None:
        self.center = t.mean(dim=0) if t.numel() else t.new_zeros(3)
        self.sigma_t, self.kappa, self.kernel = sigma_t, kappa, kernel
        self.dtype = t.dtype
        precise = torch.float64 if t.dtype == torch.float32 else t.dtype
        tc = t - self.center
        spread = float(tc.norm(dim=1).max()) if t.numel() else 0.0
        loss_t = _EPS32 * (spread / sigma_t) ** 2 * (4.0 if kernel == "gaussian" else 1.0)
        self.position_dtype = precise if loss_t > EXPONENT_TOLERANCE else t.dtype
        self.direction_dtype = precise if _EPS32 * kappa * 4.0 > EXPONENT_TOLERANCE else t.dtype
        tc = (t.to(self.position_dtype) - self.center.to(self.position_dtype)).contiguous()
        sq = (tc * tc).sum(dim=1, keepdim=True)
        ones = torch.ones_like(sq)
        if kernel == "gaussian":
            self.features = torch.cat([tc, ones, -sq / (2 * sigma_t**2)], dim=1)
        else:
            self.features = torch.cat([tc, ones, sq], dim=1)
        self.t = tc.to(t.dtype)
        self.u = _unit(u, self.direction_dtype)
        self.weights = weights

    def query_features(self, t: torch.Tensor, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(Q, 3), (Q, D) queries -> (Q, 5) position features, (Q, D) unit directions, in
        the terms' dtypes."""
        tc = t.to(self.position_dtype) - self.center.to(self.position_dtype)
        sq = (tc * tc).sum(dim=1, keepdim=True)
        ones = torch.ones_like(sq)
        if self.kernel == "gaussian":
            s2 = self.sigma_t**2
            feats = torch.cat([tc / s2, -sq / (2 * s2), ones], dim=1)
        else:
            feats = torch.cat([-2 * tc, sq, ones], dim=1)
        return feats, _unit(u, self.direction_dtype)


def _unit(u: torch.Tensor, dtype: torch.dtype) -> torch.Tensor:
    """Directions in ``dtype``, renormalised there when it is wider than theirs: a float32
    unit vector's norm is 1 only to about 1e-7, which kappa would multiply."""
    if dtype == u.dtype:
        return u
    return F.normalize(u.to(dtype), dim=-1)


def _mm(a: torch.Tensor, b: torch.Tensor, out: torch.Tensor) -> torch.Tensor:
    """A @ b.T into ``out``, computed in the inputs' dtype."""
    if a.dtype == out.dtype:
        return torch.mm(a, b.T, out=out)
    return out.copy_(torch.mm(a, b.T))


def kernel_block(
    query_feats: torch.Tensor,
    query_dirs: torch.Tensor,
    part_feats: torch.Tensor,
    part_dirs: torch.Tensor,
    terms: PairTerms,
    cutoff: float | None,
    out: torch.Tensor,
    scratch: torch.Tensor,
) -> torch.Tensor:
    """Unnormalised kernel values for a block of queries x particles, computed in place.

    Args:
        query_feats: (Q, 5) from PairTerms.query_features.
        query_dirs: (Q, D) query directions from PairTerms.query_features.
        part_feats: (N, 5) particle position features.
        part_dirs: (N, D) particle directions.
        terms: kernel constants.
        cutoff: positional truncation radius in units of sigma_t, or None.
        out: (>= Q*N,) buffer receiving the (Q, N) kernel matrix.
        scratch: (>= Q*N,) second buffer.

    Returns:
        (Q, N) view of ``out`` with the kernel values K(x_q; x_i) in [0, 1].
    """
    q, n = query_feats.shape[0], part_feats.shape[0]
    pos = out[: q * n].view(q, n)
    ang = scratch[: q * n].view(q, n)
    if query_dirs.dtype == ang.dtype:
        torch.mm(query_dirs, part_dirs.T, out=ang)
        ang.abs_().sub_(1.0).mul_(terms.kappa)
    else:  # (|u . u_i| - 1) cancels: take it in float64 before kappa scales it
        ang.copy_(torch.mm(query_dirs, part_dirs.T).abs_().sub_(1.0).mul_(terms.kappa))
    _mm(query_feats, part_feats, pos)
    if terms.kernel == "gaussian":
        if cutoff is not None:
            # pos = -d^2 / (2 s^2); truncate d > cutoff * s to a value exp() sends to 0.
            F.threshold_(pos, -0.5 * cutoff**2, -1e30)
        return floored_exp_(pos.add_(ang))
    # Triangular: pos holds d^2; the kernel is max(0, 1 - d / (2 s)).
    pos.clamp_(min=0.0).sqrt_().mul_(-0.5 / terms.sigma_t).add_(1.0)
    F.threshold_(pos, 1.0 - 0.5 * min(cutoff, 2.0) if cutoff is not None else 0.0, 0.0)
    return pos.mul_(floored_exp_(ang))
