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

import roma
import torch
from torch import Tensor

from vistask.checks import check_at_least, check_device, check_positive, checked
from vistask.objects.depth import SCREEN_POINTS, DepthCheck, evenly_spaced
from vistask.objects.messages import (
    Evidence,
    NBPResult,
    SceneMatch,
    matched_count,
    multiply,
    push_up,
    scene_evidence,
    top_down,
)
from vistask.objects.model import ObjectModel
from vistask.se3 import SE3KDE, compose, identity_poses, inverse
from vistask.se3.kernels import check_bandwidth
from vistask.vision import Patches

WIDER_CLASSES = 2.0
"""Factor on the appearance classes' radii when too few scene patches fall within them."""

MODE_ITERATIONS = 10
"""Mean-shift iterations of the object belief's modes."""

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


@checked
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
            (``vistask.objects.pair_votes``); every reference's most voted poses are
            screened against the depth images and the ``n_modes`` best join the hypotheses
            too. 0 disables the votes.
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
            not positive, floor outside [0, 1], a count or chroma_sigma negative, or cutoff not
            positive.
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
        pair_references: int = 120,
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
            refine_iters=refine_iters,
        )
        check_bandwidth(sigma_t, sigma_r)
        check_bandwidth(
            evidence_sigma_t, evidence_sigma_r, names=("evidence_sigma_t", "evidence_sigma_r")
        )
        if not floor <= 1:
            raise ValueError(f"floor must be in [0, 1], got {floor}")
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
        device = check_device(device or "cpu")
        gen = torch.Generator(device=device).manual_seed(seed)
        patches = patches.to(device)
        sigmas = (self.evidence_sigma_t, self.evidence_sigma_r)
        evidence = scene_evidence(model, patches, *sigmas, device)
        matched, radius_scale = matched_count(evidence), 1.0
        if matched < self.min_matches:
            wider = scene_evidence(model, patches, *sigmas, device, radius_scale=WIDER_CLASSES)
            if matched_count(wider) > matched:
                evidence, radius_scale = wider, WIDER_CLASSES
        if all(e is None for e in evidence.values()):
            raise ValueError(f"no scene patch matches the appearance of {model.name!r}")

        n, sigma_t, sigma_r = self.n_particles, self.sigma_t, self.sigma_r
        messages, beliefs = self._bottom_up(model, evidence, n, gen)
        object_belief = self._object_belief(model, beliefs[model.root])
        candidates, _ = object_belief.modes(
            k=self.n_modes, n_starts=self.mode_starts, n_iter=MODE_ITERATIONS, generator=gen
        )
        points, normals = model.patches.positions.cpu(), model.patches.normals.cpu()
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
                voted, _ = table.vote(patches.frames(), self.pair_references, gen, prefer)
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
            candidates = depth.refine(candidates.cpu(), points, DEPTH_REFINE_ITERS, normals)
            fit, explained = self._depth_terms(model, candidates, depth)
            if self.turns:
                # A few patches in sight can leave a quarter or half turn open that their
                # votes never proposed: the best hypotheses are tried turned as well.
                best = torch.argsort(fit * explained, descending=True)[: self.turns]
                centre = points.mean(dim=0)
                turned = self._screened(model, turn_about(candidates[best], centre), depth)
                turned = depth.refine(turned, points, DEPTH_REFINE_ITERS, normals)
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
