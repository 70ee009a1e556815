"""The messages of nonparametric belief propagation over an object model (paper Sect. 3.3):
scene evidence, bottom-up pushes and products of densities, the top-down pass, and the match
of model instances against scene observations that scores a pose."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import roma
import torch
from torch import Tensor

from vistask.checks import checked
from vistask.objects.depth import evenly_spaced
from vistask.objects.model import ObjectModel, appearance_descriptors
from vistask.se3 import SE3KDE, compose, inverse, kernels, rigid_refit
from vistask.vision import Patches

NORMAL_TOLERANCE = 0.5
"""Radians; the normal-agreement scale of the refinement's soft correspondences."""

TYPICAL_PARTICLES = 128
"""A message's typical value (``multiply``'s floor) is the median over this many of its
particles."""


def _normals(frames: Tensor) -> Tensor:
    """(..., 7) patch frames -> (..., 3) their z axes (the surface normals)."""
    z = torch.zeros_like(frames[..., :3])
    z[..., 2] = 1.0
    return roma.quat_action(frames[..., 3:], z, is_normalized=True)


@checked
@dataclass
class Evidence:
    """Observations bound to one primitive feature.

    Attributes:
        density: phi_k, a density of the world frames of the matching scene patches (M of them).
        colors: (M, 6) their appearance descriptors.
    """

    density: SE3KDE
    colors: Tensor


@checked
@dataclass
class NBPResult:
    """Output of ``NBP.infer``.

    Attributes:
        poses: (H, 7) object-pose hypotheses (world), best first.
        scores: (H,) top-down support of each: the soft count of model patches whose
            predicted pose matches an observed patch of the same appearance; with depth
            images instead, the square of the depth weight times the share of the most
            explained points that it explains and its colour agreement
            (``NBP.chroma_sigma``).
        object_belief: density of the object pose (the root's belief in the object frame).
        messages: feature index -> bottom-up message to its parent (None without evidence).
        beliefs: feature index -> bottom-up belief of meta-features, and top-down beliefs of
            every feature when requested.
        evidence: primitive feature -> its observations (None when nothing matched).
    """

    poses: Tensor
    scores: Tensor
    object_belief: SE3KDE
    messages: dict[int, SE3KDE | None] = field(default_factory=dict)
    beliefs: dict[int, SE3KDE] = field(default_factory=dict)
    evidence: dict[int, Evidence | None] = field(default_factory=dict)

    @property
    def pose(self) -> Tensor:
        """(7,) the best hypothesis."""
        return self.poses[0]


@checked
def scene_evidence(
    model: ObjectModel,
    patches: Patches,
    sigma_t: float = 0.004,
    sigma_r: float = 0.35,
    device: torch.device | str | None = None,
    radius_scale: float = 1.0,
) -> dict[int, Evidence | None]:
    """Observation potentials: per primitive feature, a density of the matching patch frames.

    Args:
        model: the object model.
        patches: (M) world-frame scene patches with normals.
        sigma_t, sigma_r: bandwidth (metres, radians) of the observation potentials.
        device: device of the densities (default: the patches').
        radius_scale: factor on the appearance classes' radii (``ObjectModel.classify``).

    Raises:
        ValueError: no patches, or patches without normals.
    """
    if len(patches) == 0:
        raise ValueError("empty scene: no patches to match the model against")
    if patches.normals is None:
        raise ValueError("scene patches need normals (full patch frames)")
    device = device or patches.device
    classes = model.classify(patches.colors.cpu(), radius_scale).to(device)
    frames = patches.frames().to(device)
    colors = appearance_descriptors(patches.colors).to(device)
    out: dict[int, Evidence | None] = {}
    for i in model.leaves():
        mine = classes == model.features[i].appearance
        out[i] = None
        if mine.any():
            density = SE3KDE(frames[mine], sigma_t=sigma_t, sigma_r=sigma_r)
            out[i] = Evidence(density, colors[mine])
    return out


def matched_count(evidence: dict[int, Evidence | None]) -> int:
    """Number of scene patches bound to some primitive feature."""
    return sum(len(e.colors) for e in evidence.values() if e is not None)


@checked
def push_up(
    density: SE3KDE,
    potential: SE3KDE,
    n: int,
    sigma_t: float,
    sigma_r: float,
    generator: torch.Generator,
) -> SE3KDE:
    """Message to the parent: X_p = X_c ∘ inverse(r), X_c ~ ``density``, r ~ ``potential``.

    With few enough pairs every (particle, potential particle) pair votes once (weighted);
    otherwise n pairs are drawn by their weights.

    Returns:
        a density of the parent's pose with bandwidth (sigma_t, sigma_r).
    """
    device = density.device
    pot_points = potential.points.to(device)
    pot_weights = potential.weights.to(device)
    m, r = len(density), len(pot_points)
    if m * r <= n:
        i = torch.arange(m, device=device).repeat_interleave(r)
        j = torch.arange(r, device=device).repeat(m)
        weights = density.weights[i] * pot_weights[j]
    else:
        i = torch.multinomial(density.weights, n, replacement=True, generator=generator)
        j = torch.multinomial(pot_weights, n, replacement=True, generator=generator)
        weights = None
    votes = compose(density.points[i], inverse(pot_points[j]))
    return SE3KDE(votes, weights, sigma_t=sigma_t, sigma_r=sigma_r)


@checked
def multiply(
    messages: list[SE3KDE],
    n: int,
    floor: float,
    cutoff: float | None,
    generator: torch.Generator,
) -> SE3KDE:
    """Product of messages by importance sampling from their mixture.

    Candidates are drawn from the equal mixture of the messages' particles; each gets weight
    prod_c (f_c(x) + floor_c) / mean_c f_c(x), floor_c = ``floor`` times the median of f_c at
    its own particles.

    Args:
        messages: C >= 1 densities over the same variable.
        n: number of candidates.
        floor: share of a message's typical value added to it, so that a message without
            evidence lowers a candidate's weight without vetoing it.
        cutoff: kernel cut-off (multiples of sigma_t) of the evaluations, or None.
        generator: random generator.

    Returns:
        the product density (bandwidth of the first message).
    """
    if len(messages) == 1:
        return messages[0]
    first = messages[0]
    device = first.device
    points = torch.cat([m.points for m in messages])
    mix = torch.cat([m.weights / len(messages) for m in messages])
    idx = torch.multinomial(mix, min(n, len(points)), replacement=True, generator=generator)
    x = points[torch.unique(idx)]
    values = torch.stack([m.evaluate(x, cutoff=cutoff) for m in messages])  # (C, n)
    log_w = -values.mean(dim=0).clamp_min(1e-30).log()
    for m, v in zip(messages, values, strict=True):
        own = evenly_spaced(m.points, TYPICAL_PARTICLES)
        typical = m.evaluate(own, cutoff=cutoff).median() if floor > 0 else 0.0
        log_w = log_w + (v + floor * typical).clamp_min(1e-30).log()
    w = torch.softmax(log_w, dim=0)
    return SE3KDE(x, w.to(device), sigma_t=first.sigma_t, sigma_r=first.sigma_r)


@checked
@dataclass
class SceneMatch:
    """Model instances against scene observations, for top-down checks of object poses.

    An instance matches only observations of its own primitive feature, so the match is
    kept in blocks, one per feature with observations: the work is the sum of the blocks'
    sizes, not all instances times all observations.

    Attributes:
        instances: (N, 7) object-frame frames of every model patch of a primitive feature,
            grouped by feature.
        observed: (M, 7) world frames of the scene patches bound to a primitive feature,
            grouped the same way.
        blocks: per feature, its instances' slice of ``instances``, its observations' slice
            of ``observed``, and the log of their colour similarity, -d^2 / 2 s^2 (N_k, M_k).
    """

    instances: Tensor
    observed: Tensor
    blocks: list[tuple[slice, slice, Tensor]]

    @classmethod
    def build(
        cls, model: ObjectModel, evidence: dict[int, Evidence | None], color_sigma: float
    ) -> SceneMatch:
        """The match of ``model`` against ``evidence``; ``color_sigma`` scales the colour
        similarity."""
        inst, obs, blocks = [], [], []
        n = m = 0
        for leaf, ev in evidence.items():
            if ev is None:
                continue
            k = model.features[leaf].appearance
            inst.append(model.instances(k).to(ev.colors))
            obs.append(ev.density.points)
            d2 = torch.cdist(model.instance_colors(k).to(ev.colors), ev.colors).square()
            size_n, size_m = len(inst[-1]), len(obs[-1])
            blocks.append(
                (
                    slice(n, n + size_n),
                    slice(m, m + size_m),
                    -0.5 * d2 / color_sigma**2,
                )
            )
            n, m = n + size_n, m + size_m
        return cls(torch.cat(inst), torch.cat(obs), blocks)

    def predict(self, poses: Tensor) -> Tensor:
        """(H, 7) object poses -> (H, N, 7) world frames of the model instances."""
        return compose(poses[:, None], self.instances[None])

    def support(self, poses: Tensor, sigma_t: float, sigma_r: float) -> Tensor:
        """(H, 7) object poses -> (H,) soft count of model patches whose predicted frame
        (SE(3) kernel of bandwidth sigma_t, sigma_r, peak 1) and colours match an observed
        patch of the same primitive feature."""
        pred = self.predict(poses)
        kappa = kernels.quaternion_kappa(sigma_r)
        total = torch.zeros(len(poses), dtype=pred.dtype, device=pred.device)
        for rows, cols, log_affinity in self.blocks:
            p, o = pred[:, rows], self.observed[cols]
            d2 = torch.cdist(p[..., :3], o[None, :, :3]).square()
            dot = (p[..., 3:] @ o[:, 3:].T).abs()
            kern = kernels.floored_exp_(-0.5 * d2 / sigma_t**2 + kappa * (dot - 1.0) + log_affinity)
            total = total + kern.amax(dim=2).sum(dim=1)
        return total

    def refine(self, poses: Tensor, sigma_t: float, iters: int) -> Tensor:
        """Sharpen hypotheses (H, 7) -> (H, 7): each predicted instance is pulled to the
        kernel-weighted mean of the matching observed positions (position kernel at scale
        ``sigma_t``, normal agreement, affinity), then the weighted rigid fit of the model
        to the pulled points (Kabsch) gives the new pose. A hypothesis with fewer than
        three matching instances stays where it is."""
        obs_t, obs_n = self.observed[:, :3], _normals(self.observed)
        source = self.instances[:, :3].expand(len(poses), -1, -1)
        for _ in range(iters):
            pred = self.predict(poses)  # (H, N, 7)
            pred_t, pred_n = pred[..., :3], _normals(pred)
            target, total = torch.zeros_like(pred_t), torch.zeros_like(pred_t[..., 0])
            for rows, cols, log_affinity in self.blocks:
                # Axial normal agreement keeps patches of other faces out of the match.
                cos = (pred_n[:, rows] @ obs_n[cols].T).abs()
                log_kern = -0.5 * torch.cdist(pred_t[:, rows], obs_t[None, cols]).square()
                log_kern = log_kern / sigma_t**2 + (cos - 1.0) / (1.0 - math.cos(NORMAL_TOLERANCE))
                kern = kernels.floored_exp_(log_kern + log_affinity)
                total[:, rows] = kern.sum(dim=2)
                target[:, rows] = kern @ obs_t[cols]
            target = target / total.clamp_min(1e-6)[..., None]
            weights = torch.where(total > 1e-6, total.clamp(max=1.0), 0.0)
            poses, moved = rigid_refit(poses, source, target, weights, 3)
            if not moved:
                break
        return poses


@checked
def top_down(
    model: ObjectModel,
    result: NBPResult,
    n: int,
    sigma_t: float,
    sigma_r: float,
    cutoff: float | None,
    generator: torch.Generator,
) -> dict[int, SE3KDE]:
    """Top-down pass: every feature's belief given the root's (X_c = X_p ∘ r, r ~ psi_pc,
    reweighted by the child's bottom-up belief or evidence).

    Args:
        model: the object model.
        result: the bottom-up pass (its root belief and evidence are used).
        n: particles per belief.
        sigma_t, sigma_r: bandwidth of the beliefs.
        cutoff: kernel cut-off (multiples of sigma_t) of the reweighting, or None.
        generator: random generator.

    Returns:
        feature index -> belief of its world pose.
    """
    root = model.root
    out: dict[int, SE3KDE] = {root: result.beliefs[root]}
    stack = [root]
    while stack:
        p = stack.pop()
        parent = out[p]
        for c in model.features[p].children:
            pot = model.features[c].potential
            assert pot is not None
            i = torch.multinomial(parent.weights, n, replacement=True, generator=generator)
            j = torch.multinomial(pot.weights.to(parent.device), n, True, generator=generator)
            x = compose(parent.points[i], pot.points.to(parent.device)[j])
            ev = result.evidence.get(c)
            local = result.beliefs.get(c) if c in result.beliefs else ev and ev.density
            w = None
            if local is not None:
                w = local.evaluate(x, cutoff=cutoff)
                w = None if not (w.sum() > 0) else w
            out[c] = SE3KDE(x, w, sigma_t=sigma_t, sigma_r=sigma_r)
            if not model.features[c].is_primitive:
                stack.append(c)
    return out
