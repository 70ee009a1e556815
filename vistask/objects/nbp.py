"""Nonparametric belief propagation over an object model's Markov tree (paper Sect. 3.3).

Every density is an ``SE3KDE`` over world poses of a feature's frame.

- Evidence: the observed scene patches of appearance class k, as a density of their frames,
  is the observation potential phi_k of primitive feature k.
- Bottom-up: a primitive feature's message to its parent p is its evidence pushed through
  psi_pk: X_p = X_k ∘ inverse(r), X_k an observed frame, r a particle of psi_pk (each observed
  patch votes for every parent pose it could belong to). A meta-feature multiplies its
  incoming messages by importance sampling (proposal: the mixture of the messages; a floor
  keeps a child without evidence, e.g. occluded, from vetoing) and pushes the product to its
  own parent the same way.
- The root's belief, mapped to the object frame, gives pose hypotheses (its modes, by mean
  shift); each is scored by the top-down prediction of every primitive instance against the
  evidence (how much of the model the scene explains), best first. Given the depth images
  (``DepthCheck``), poses screened against the depth join the modes: poses drawn from the
  belief, poses that pairs of scene patches vote for by their geometry, whatever their
  appearance (``vistask.objects.pair_votes``: other light or an unseen side can mislead the
  appearance, not the geometry), and the modes of regions of matching patches searched on
  their own (a target that shows a few patches among lookalikes leads no mode of the whole
  scene). Each hypothesis is pulled onto the observed surfaces, the best are tried turned by
  quarter and half turns as well, and the depth scores them instead of the patches: the
  square of how much of the model the depth explains, less what it rules out, times how
  many of its points the depth explains against the best hypothesis, and, where the model
  holds its surface's colours, times how well they match the pixels under it
  (``DepthCheck.colour_agreement``): a few patches leave an object's yaw open, its texture
  under the whole visible surface does not. Draws are screened against the depth images
  and these colours alike.
- Top-down: the root's belief is pushed down through the potentials (X_c = X_p ∘ r) and
  reweighted by each child's bottom-up belief (meta) or evidence (primitive), which gives a
  belief for every feature.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import roma
import torch
from torch import Tensor

from vistask.checks import check_at_least, check_positive
from vistask.objects.depth import SCREEN_POINTS, DepthCheck, evenly_spaced
from vistask.objects.model import ObjectModel, appearance_descriptors
from vistask.se3 import SE3KDE, compose, identity_poses, inverse, kernels, rigid_refit
from vistask.vision import Patches

NORMAL_TOLERANCE = 0.5
"""Radians; the normal-agreement scale of the refinement's soft correspondences."""

WIDER_CLASSES = 2.0
"""Factor on the appearance classes' radii when too few scene patches fall within them."""

VOTED_POSES = 32
"""Poses most voted for by patch pairs (``PairTable.vote``) that are screened against the
depth images."""

MODE_ITERATIONS = 10
"""Mean-shift iterations of the object belief's modes."""

TYPICAL_PARTICLES = 128
"""A message's typical value (``multiply``'s floor) is the median over this many of its
particles."""

DEPTH_REFINE_ITERS = 2
"""Iterations a scale of the depth refinement of the hypotheses (``DepthCheck.refine``): they
come near already; 3 found one more pose in clutter (216 against 215 of 240) in 8% more time."""

REGION_LINK_M = 0.015
"""Scene patches that match the model's appearance and lie within this of each other (in
chains) form one region (``link_groups``)."""

REGION_RADIUS_M = 0.06
"""A region's search takes the matching patches within this of its centre."""

MIN_REGION_PATCHES = 3
"""Smaller regions are not searched on their own."""

REGION_PARTICLES = 250
"""Particles per message and belief of a region's search."""

REGION_MODES = 2
"""Modes of each region's object belief that become pose candidates."""


QUARTER_AND_HALF_TURNS = torch.stack(
    [
        roma.rotvec_to_unitquat(axis * turn * math.pi)
        for axis in torch.eye(3)
        for turn in (0.5, 1, -0.5)
    ]
)
"""(9, 4) unit quaternions (x, y, z, w): quarter, half and minus-quarter turns about the x,
y and z axes."""


def turn_about(poses: Tensor, centre: Tensor) -> Tensor:
    """Every pose turned by each of ``QUARTER_AND_HALF_TURNS`` about its own axes through a
    point of its frame.

    Args:
        poses: (H, 7) object poses (world).
        centre: (3,) the point the turns keep in place, in the object frame.

    Returns:
        (9 H, 7) the turned poses, the 9 turns of the first pose first.

    Example:
        >>> turn_about(poses, model.patches.positions.mean(dim=0)).shape  # poses: (4, 7)
        torch.Size([36, 7])
    """
    k = len(QUARTER_AND_HALF_TURNS)
    turns = torch.cat([torch.zeros(k, 3), QUARTER_AND_HALF_TURNS], dim=1).to(poses)
    shift = identity_poses(1).to(poses)[0]
    shift[:3] = centre
    about = compose(compose(shift, turns), inverse(shift))  # (9, 7)
    return compose(poses[:, None], about).reshape(-1, 7)


def _normals(frames: Tensor) -> Tensor:
    """(..., 7) patch frames -> (..., 3) their z axes (the surface normals)."""
    z = torch.zeros_like(frames[..., :3])
    z[..., 2] = 1.0
    return roma.quat_action(frames[..., 3:], z, is_normalized=True)


@dataclass
class Evidence:
    """Observations bound to one primitive feature.

    Attributes:
        density: phi_k, a density of the world frames of the matching scene patches (M of them).
        colors: (M, 6) their appearance descriptors.
    """

    density: SE3KDE
    colors: Tensor


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


def _matched(evidence: dict[int, Evidence | None]) -> int:
    """Number of scene patches bound to some primitive feature."""
    return sum(len(e.colors) for e in evidence.values() if e is not None)


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


def link_groups(positions: Tensor, link: float) -> Tensor:
    """Groups of points joined by chains of steps shorter than ``link`` (single linkage).

    Args:
        positions: (M, 3) points.
        link: metres.

    Returns:
        (M,) the group of each point, named by its smallest point index.
    """
    near = torch.cdist(positions, positions) < link
    label = torch.arange(len(positions), device=positions.device)
    while True:
        # Each point takes the smallest label among its neighbours (itself included) until
        # every group carries its smallest index.
        new = torch.where(near, label[None, :], len(positions)).amin(dim=1)
        if torch.equal(new, label):
            return label
        label = new


class NBP:
    """Pose estimation by nonparametric belief propagation over an object model's tree.

    ``NBP(n_particles=800).infer(model, patches)`` detects the object and returns its pose
    hypotheses (see the module docstring for the passes). The arguments are kept as
    attributes of the same names.

    Args:
        n_particles: particles per message and belief.
        sigma_t, sigma_r: bandwidth (metres, radians) of messages and beliefs; wider than the
            potentials because a patch's orientation error moves its vote by the lever arm.
        evidence_sigma_t, evidence_sigma_r: bandwidth of the observation potentials.
        floor: a child message counts at least ``floor`` times its typical value, so a
            feature without evidence (occluded) lowers a pose's weight but does not zero it.
        cutoff: SE(3) kernel cut-off in multiples of sigma_t (grid evaluation), or None for
            dense evaluation, which is faster at these particle counts: votes crowd around
            the true pose, where the grid saves little.
        n_modes: modes of the object belief kept as pose hypotheses (several object
            instances, or ambiguous poses).
        depth_draws: with depth images, poses drawn from the object belief and screened
            against them; the ``n_modes`` best join the modes as hypotheses.
        pair_references: with depth images, scene patches that pair with their neighbours
            to vote for poses by the pairs' geometry, whatever their appearance
            (``vistask.objects.pair_votes``); the ``VOTED_POSES`` most voted are screened
            against the depth images and the ``n_modes`` best join the hypotheses too. 0
            disables the votes.
        regions: with depth images, the largest regions of scene patches that match the
            model's appearance (``link_groups``) searched on their own: a target that shows
            a few patches among lookalikes gets no mode of the whole scene's belief, but
            leads its region's. The modes of each region's belief are screened against the
            depth images and the ``n_modes`` best join the hypotheses. 0 disables them.
        turns: with depth images, the hypotheses the depth supports best are also tried
            turned by quarter and half turns about the object's axes through the centre of
            its points (``turn_about``): of an object mostly hidden, what shows can fit a
            turned pose that no vote proposed. 0 disables them.
        mode_starts: mean-shift starts for the modes.
        refine_sigma_t: position scale (metres) of the final top-down refinement; 0 disables.
        refine_iters: iterations of that refinement.
        color_sigma: scale of the colour similarity (descriptor distance) used when checking
            and refining hypotheses against observed patches.
        min_matches: when fewer scene patches than this fall within the model's appearance
            classes, they are matched again within classes of ``WIDER_CLASSES`` times the
            radius: other light moves the colours of a plain object, whose classes are
            tight, out of them.
        chroma_sigma: with depth images and a model that holds its surface's colours, the
            scale of the chromaticity difference of ``DepthCheck.colour_agreement``, which
            weighs each hypothesis and each screened draw; 0 disables it.
        top_down: also compute every feature's top-down belief.

    Raises:
        ValueError: n_particles, n_modes or mode_starts below 1, a bandwidth or color_sigma
            not positive, floor, refine_sigma_t, min_matches or chroma_sigma negative, or
            cutoff not positive.
    """

    def __init__(
        self,
        n_particles: int = 2000,
        sigma_t: float = 0.01,
        sigma_r: float = 0.3,
        evidence_sigma_t: float = 0.004,
        evidence_sigma_r: float = 0.35,
        floor: float = 0.05,
        cutoff: float | None = None,
        n_modes: int = 4,
        depth_draws: int = 128,
        pair_references: int = 20,
        regions: int = 6,
        turns: int = 2,
        mode_starts: int = 32,
        refine_sigma_t: float = 0.006,
        refine_iters: int = 3,
        color_sigma: float = 0.1,
        min_matches: int = 10,
        chroma_sigma: float = 0.03,
        top_down: bool = False,
    ) -> None:
        check_at_least(1, n_particles=n_particles, n_modes=n_modes, mode_starts=mode_starts)
        check_positive(
            sigma_t=sigma_t,
            sigma_r=sigma_r,
            evidence_sigma_t=evidence_sigma_t,
            evidence_sigma_r=evidence_sigma_r,
            color_sigma=color_sigma,
        )
        check_at_least(
            0,
            floor=floor,
            refine_sigma_t=refine_sigma_t,
            depth_draws=depth_draws,
            pair_references=pair_references,
            regions=regions,
            turns=turns,
            min_matches=min_matches,
            chroma_sigma=chroma_sigma,
        )
        if cutoff is not None and not cutoff > 0:
            raise ValueError(
                f"cutoff must be positive (multiples of sigma_t) or None, got {cutoff}"
            )
        self.n_particles = n_particles
        self.sigma_t = sigma_t
        self.sigma_r = sigma_r
        self.evidence_sigma_t = evidence_sigma_t
        self.evidence_sigma_r = evidence_sigma_r
        self.floor = floor
        self.cutoff = cutoff
        self.n_modes = n_modes
        self.depth_draws = depth_draws
        self.pair_references = pair_references
        self.regions = regions
        self.turns = turns
        self.mode_starts = mode_starts
        self.refine_sigma_t = refine_sigma_t
        self.refine_iters = refine_iters
        self.color_sigma = color_sigma
        self.min_matches = min_matches
        self.chroma_sigma = chroma_sigma
        self.top_down = top_down

    def infer(
        self,
        model: ObjectModel,
        patches: Patches,
        device: torch.device | str | None = None,
        seed: int = 0,
        depth: DepthCheck | None = None,
    ) -> NBPResult:
        """Detect the object and estimate its pose in a scene.

        Args:
            model: the learned object model.
            patches: (M) world-frame scene patches (with normals).
            device: where to compute (default CPU).
            seed: seed of the sampling.
            depth: the scene's depth images; when given, every hypothesis is refined onto
                the observed surfaces and scored by them (``NBPResult.scores``).

        Returns:
            the pose hypotheses and the densities computed on the way.

        Raises:
            ValueError: empty scene, or no scene patch matches the model's appearance.
        """
        device = torch.device(device or "cpu")
        gen = torch.Generator(device=device).manual_seed(seed)
        patches = patches.to(device)
        sigmas = (self.evidence_sigma_t, self.evidence_sigma_r)
        evidence = scene_evidence(model, patches, *sigmas, device)
        matched, radius_scale = _matched(evidence), 1.0
        if matched < self.min_matches:
            wider = scene_evidence(model, patches, *sigmas, device, radius_scale=WIDER_CLASSES)
            if _matched(wider) > matched:
                evidence, radius_scale = wider, WIDER_CLASSES
        if all(e is None for e in evidence.values()):
            raise ValueError(f"no scene patch matches the appearance of {model.name!r}")

        n, sigma_t, sigma_r = self.n_particles, self.sigma_t, self.sigma_r
        messages, beliefs = self._bottom_up(model, evidence, n, gen)
        object_belief = self._object_belief(model, beliefs[model.root])
        candidates, _ = object_belief.modes(
            k=self.n_modes, n_starts=self.mode_starts, n_iter=MODE_ITERATIONS, generator=gen
        )
        points = model.patches.positions.cpu()
        if depth is not None:
            # Modes follow the votes; a target mostly hidden among lookalikes gets few, and
            # one under other light or tipped onto an unseen side gets misleading ones. Poses
            # the depth supports are also taken from the belief's particles, from the votes
            # of patch pairs, whatever their appearance, and from the beliefs of regions.
            sources = []
            if self.depth_draws:
                weights = object_belief.weights
                i = torch.multinomial(weights, self.depth_draws, True, generator=gen)
                sources.append(object_belief.points[i])
            if self.pair_references:
                table = model.pair_table()
                prefer = model.classify(patches.colors.cpu(), radius_scale) >= 0
                voted, _ = table.vote(
                    patches.frames(), self.pair_references, VOTED_POSES, gen, prefer
                )
                sources.append(voted)
            if self.regions:
                sources.append(self._region_modes(model, evidence, gen))
            candidates = torch.cat(
                [candidates, *(self._screened(model, d, depth) for d in sources)]
            )
        match = SceneMatch.build(model, evidence, self.color_sigma)
        if self.refine_sigma_t > 0:
            candidates = match.refine(candidates, self.refine_sigma_t, self.refine_iters)
        if depth is None:
            scores = match.support(candidates, self.evidence_sigma_t, self.evidence_sigma_r)
        else:
            candidates = depth.refine(candidates.cpu(), points, DEPTH_REFINE_ITERS)
            fit, explained = self._depth_terms(model, candidates, depth)
            if self.turns:
                # A few patches in sight can leave a quarter or half turn open that their
                # votes never proposed: the best hypotheses are tried turned as well.
                best = torch.argsort(fit * explained, descending=True)[: self.turns]
                centre = points.mean(dim=0)
                turned = self._screened(model, turn_about(candidates[best], centre), depth)
                turned = depth.refine(turned, points, DEPTH_REFINE_ITERS)
                fit_t, explained_t = self._depth_terms(model, turned, depth)
                candidates = torch.cat([candidates, turned])
                fit, explained = torch.cat([fit, fit_t]), torch.cat([explained, explained_t])
            candidates = candidates.to(device)
            scores = (fit * explained / explained.max().clamp_min(1)).to(device)
        order = torch.argsort(scores, descending=True)
        result = NBPResult(
            candidates[order], scores[order], object_belief, messages, beliefs, evidence
        )
        if self.top_down:
            result.beliefs.update(top_down(model, result, n, sigma_t, sigma_r, self.cutoff, gen))
        return result

    def _screened(self, model: ObjectModel, draws: Tensor, depth: DepthCheck) -> Tensor:
        """The ``n_modes`` of (K, 7) ``draws`` that ``SCREEN_POINTS`` of the model's points
        and surface fit best to the depth images and their colours."""
        screen = evenly_spaced(model.patches.positions.cpu(), SCREEN_POINTS)
        fit = depth.weights(draws.cpu(), screen) * self._colours(model, draws, depth, True)
        return draws[torch.argsort(fit, descending=True)[: self.n_modes].to(draws.device)]

    def _depth_terms(
        self, model: ObjectModel, poses: Tensor, depth: DepthCheck
    ) -> tuple[Tensor, Tensor]:
        """The depth's verdict on (H, 7) poses: (H,) the square of ``DepthCheck.weights``
        times ``_colours``, and (H,) the number of model points the depth explains.

        The appearance support of the patches is left out: in clutter a few lookalike
        patches give a wrong pose a higher count than the true one, whose visible surface
        the depth and colours explain better (on the pose benchmark's 60 clutter scenes,
        four NBP seeds, the same hypotheses: 218 of 240 right without it, 202 with it)."""
        fit, explained = depth.explain(poses, model.patches.positions.cpu())
        return fit**2 * self._colours(model, poses, depth), explained

    def _colours(
        self, model: ObjectModel, poses: Tensor, depth: DepthCheck, screen: bool = False
    ) -> Tensor:
        """(H,) ``DepthCheck.colour_agreement`` of ``poses`` with the model's
        surface (``SCREEN_POINTS`` of it to ``screen`` many draws), or ones when the model
        holds no surface or the check is off."""
        if model.surface is None or not self.chroma_sigma:
            return torch.ones(len(poses))
        surface = evenly_spaced(model.surface, SCREEN_POINTS) if screen else model.surface
        return depth.colour_agreement(poses.cpu(), surface, self.chroma_sigma)

    def _bottom_up(
        self,
        model: ObjectModel,
        evidence: dict[int, Evidence | None],
        n: int,
        gen: torch.Generator,
    ) -> tuple[dict[int, SE3KDE | None], dict[int, SE3KDE]]:
        """Bottom-up pass with ``n`` particles: every feature's message to its parent (None
        without evidence), and the beliefs of the meta-features that get a message."""
        sigma_t, sigma_r = self.sigma_t, self.sigma_r
        messages: dict[int, SE3KDE | None] = {}
        beliefs: dict[int, SE3KDE] = {}
        for i in model.leaves():
            ev, pot = evidence[i], model.features[i].potential
            messages[i] = (
                None
                if ev is None or pot is None
                else push_up(ev.density, pot, n, sigma_t, sigma_r, gen)
            )
        for i in model.bottom_up_order():
            feature = model.features[i]
            incoming = [messages[c] for c in feature.children if messages[c] is not None]
            if not incoming:
                messages[i] = None
                continue
            beliefs[i] = multiply(incoming, n, self.floor, self.cutoff, gen)
            pot = feature.potential
            messages[i] = (
                None if pot is None else push_up(beliefs[i], pot, n, sigma_t, sigma_r, gen)
            )
        return messages, beliefs

    def _object_belief(self, model: ObjectModel, root: SE3KDE) -> SE3KDE:
        """The root feature's belief mapped to the pose of the object frame."""
        to_object = inverse(model.features[model.root].frame.to(root.device))
        return SE3KDE(
            compose(root.points, to_object),
            root.weights,
            sigma_t=self.sigma_t,
            sigma_r=self.sigma_r,
        )

    def _region_modes(
        self, model: ObjectModel, evidence: dict[int, Evidence | None], gen: torch.Generator
    ) -> Tensor:
        """(K, 7) object poses: the ``REGION_MODES`` modes of the object belief of each of
        the ``regions`` largest regions of matched patches, computed from the evidence
        within ``REGION_RADIUS_M`` of the region's centre alone."""
        observed = torch.cat([e.density.points for e in evidence.values() if e is not None])
        positions = observed[:, :3]
        group = link_groups(positions, REGION_LINK_M)
        sizes = torch.bincount(group, minlength=len(group))
        large = torch.nonzero(sizes >= MIN_REGION_PATCHES)[:, 0]
        large = large[torch.argsort(sizes[large], descending=True)][: self.regions]
        out = [observed[:0]]
        for g in large.tolist():
            centre = positions[group == g].mean(dim=0)
            local: dict[int, Evidence | None] = dict.fromkeys(evidence)
            for i, ev in evidence.items():
                if ev is None:
                    continue
                frames, sigmas = ev.density.points, (ev.density.sigma_t, ev.density.sigma_r)
                keep = (frames[:, :3] - centre).norm(dim=-1) < REGION_RADIUS_M
                if keep.any():
                    local[i] = Evidence(SE3KDE(frames[keep], None, *sigmas), ev.colors[keep])
            _, beliefs = self._bottom_up(model, local, REGION_PARTICLES, gen)
            if model.root in beliefs:
                belief = self._object_belief(model, beliefs[model.root])
                # A region's belief has few particles and modes: a short search finds them.
                modes, _ = belief.modes(REGION_MODES, n_starts=8, n_iter=5, generator=gen)
                out.append(modes)
        return torch.cat(out)


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
