"""Object poses voted by pairs of patches: the geometry of two patches at once.

Two oriented patches a and b have a feature that a rigid motion keeps: their distance and the
angles between each normal and the line from a to b, and between the normals (the point pair
feature of Drost et al., "Model globally, match locally", 2010). ``PairTable`` files every
pair of a model's patches by its quantised feature once. In a scene, a reference patch is
paired with every patch within the model's diameter; each scene pair looks up the model pairs
of the same feature, and each match votes for a model patch under the reference patch and a
turn about its normal (the turn that points the model pair's partner where the scene pair's
partner lies). A cell that many partners vote for is a pose that many patches agree on,
whatever their appearance: one patch alone fixes a pose only as well as its orientation is
measured, and a random patch in a cluttered scene rarely lies on the target.

Example:
    >>> table = PairTable(model.patches.frames())
    >>> poses, votes = table.vote(scene.frames(), 120, torch.Generator().manual_seed(0))
"""

from __future__ import annotations

import math

import roma
import torch
from torch import Tensor

from vistask.checks import check_at_least
from vistask.se3 import compose, inverse, make_poses

DISTANCE_STEP_M = 0.008
"""Bin of the pair distance (metres), twice the spacing of a model's patches (4 mm voxels).
With NBP on the pose benchmark's 60 clutter scenes (votes alone, 40 references), bins of 8 mm
and 15 degrees, 6 mm and 12, 12 mm and 20 were right in 41, 42 and 42, the coarsest at twice
the time."""
ANGLE_STEP = math.radians(15.0)
"""Bin of the pair angles (radians)."""
TURN_BINS = 30
"""Bins of the turn about the reference patch's normal (12 degrees each)."""
PEAKS_PER_REFERENCE = 2
"""Cells each reference patch proposes (in the same clutter scenes, 4 found no more: 40)."""


def pair_features(a: Tensor, b: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """The rigid-invariant feature of patch pairs, and the partner's direction about a.

    Args:
        a, b: (P, 7) frames of the pairs' first and second patches (z axis = normal).

    Returns:
        distance (P,); angles (P, 3) in [0, pi] between a's normal and the line a -> b, b's
        normal and that line, and the two normals; turn (P,) the angle of b's position in the
        xy plane of a's frame.
    """
    ra, rb = roma.unitquat_to_rotmat(a[:, 3:]), roma.unitquat_to_rotmat(b[:, 3:])
    na, nb = ra[:, :, 2], rb[:, :, 2]
    d = b[:, :3] - a[:, :3]
    distance = d.norm(dim=-1)
    u = d / distance.clamp_min(1e-9)[:, None]
    cosines = torch.stack([(na * u).sum(-1), (nb * u).sum(-1), (na * nb).sum(-1)], dim=-1)
    local = (ra.transpose(1, 2) @ d[:, :, None])[:, :, 0]
    return distance, cosines.clamp(-1.0, 1.0).acos(), torch.atan2(local[:, 1], local[:, 0])


class PairTable:
    """Every ordered pair of a model's patches, filed by quantised pair feature.

    Args:
        frames: (N, 7) object-frame frames of the model's patches.

    Attributes:
        frames: the model's patch frames.
        diameter: the largest distance between two of them (metres).
        keys: (P,) sorted feature keys of the P pairs; ``first`` (P,) the pair's first patch,
            ``turn`` (P,) its partner's angle about the first patch's normal.
    """

    def __init__(self, frames: Tensor) -> None:
        if len(frames) < 2:
            raise ValueError(f"a pair table needs at least 2 patches, got {len(frames)}")
        self.frames = frames
        n = len(frames)
        first, second = torch.triu_indices(n, n, 1, device=frames.device)
        first, second = torch.cat([first, second]), torch.cat([second, first])
        distance, angles, turn = pair_features(frames[first], frames[second])
        self.diameter = float(distance.max())
        self._angle_bins = math.ceil(math.pi / ANGLE_STEP) + 1
        self._distance_bins = int(self.diameter / DISTANCE_STEP_M) + 2
        keys = self.key(distance, angles)
        order = torch.argsort(keys)
        self.keys, self.first, self.turn = keys[order], first[order], turn[order]

    def key(self, distance: Tensor, angles: Tensor) -> Tensor:
        """(P,) distances, (P, 3) angles -> (P,) integer keys of their bins."""
        d = (distance / DISTANCE_STEP_M).long().clamp(max=self._distance_bins - 1)
        a0, a1, a2 = (angles / ANGLE_STEP).long().clamp(max=self._angle_bins - 1).unbind(-1)
        bins = self._angle_bins
        return ((d * bins + a0) * bins + a1) * bins + a2

    def votes(self, scene: Tensor, references: Tensor) -> Tensor:
        """The votes of every pair of a reference patch and a scene patch within the model's
        diameter.

        Args:
            scene: (M, 7) world frames of the scene's patches.
            references: (R,) indices of the reference patches in ``scene``.

        Returns:
            (R, N, TURN_BINS) votes for (reference, model patch under it, turn about its
            normal); turn bin t covers [t, t + 1) * 2 pi / ``TURN_BINS``.
        """
        device, n, r = scene.device, len(self.frames), len(references)
        ref, partner = torch.cartesian_prod(
            torch.arange(r, device=device), torch.arange(len(scene), device=device)
        ).T
        distance, angles, turn = pair_features(scene[references[ref]], scene[partner])
        near = (distance > 0) & (distance <= self.diameter)
        ref, distance, angles, turn = ref[near], distance[near], angles[near], turn[near]
        keys, first, model_turn = (x.to(device) for x in (self.keys, self.first, self.turn))
        query = self.key(distance, angles)
        lo = torch.searchsorted(keys, query, side="left")
        count = torch.searchsorted(keys, query, side="right") - lo
        # Every model pair of the scene pair's key: the run keys[lo : lo + count].
        pair = torch.repeat_interleave(torch.arange(len(query), device=device), count)
        start = torch.repeat_interleave(torch.cumsum(count, 0) - count, count)
        matched = lo[pair] + torch.arange(len(pair), device=device) - start
        # The turn about the normal that brings the model partner's direction onto the
        # scene partner's.
        angle = model_turn[matched] - turn[pair]
        bins = ((angle / (2 * math.pi)) % 1.0 * TURN_BINS).long().clamp(max=TURN_BINS - 1)
        cell = (ref[pair] * n + first[matched]) * TURN_BINS + bins
        return torch.bincount(cell, minlength=r * n * TURN_BINS).view(r, n, TURN_BINS)

    def vote(
        self,
        scene: Tensor,
        n_references: int,
        generator: torch.Generator,
        prefer: Tensor | None = None,
    ) -> tuple[Tensor, Tensor]:
        """The object poses that pairs of scene patches vote for: each reference patch's
        ``PEAKS_PER_REFERENCE`` most voted cells.

        Args:
            scene: (M, 7) world frames of the scene's patches.
            n_references: reference patches drawn at random (all of them if fewer); each is
                paired with every scene patch within the model's diameter (``votes``).
            generator: the draw of the references.
            prefer: (M,) bool, patches likelier to lie on the object (their appearance
                matches it): up to half of the references are drawn among them, the rest
                among the others.

        Returns:
            (K, 7) world object poses and (K,) their votes, most voted first (K <=
            ``PEAKS_PER_REFERENCE`` n_references; none when no scene pair matches a model
            pair).
        """
        check_at_least(1, n_references=n_references)
        references = torch.randperm(len(scene), generator=generator, device=generator.device)
        if prefer is not None:
            preferred = prefer.to(references.device)[references]
            n_preferred = min(n_references // 2, int(preferred.sum()))
            references = torch.cat([references[preferred][:n_preferred], references[~preferred]])
        references = references[:n_references].to(scene.device)
        votes = self.votes(scene, references).flatten(1)
        peaks, cells = votes.topk(min(PEAKS_PER_REFERENCE, votes.shape[1]), dim=1)
        owner = torch.arange(len(references), device=scene.device)[:, None].expand_as(peaks)
        peaks, cells, owner = peaks.flatten(), cells.flatten(), owner.flatten()
        best = torch.argsort(peaks, descending=True)
        best = best[peaks[best] > 0]
        angle = (cells[best] % TURN_BINS + 0.5) * (2 * math.pi / TURN_BINS)
        model_patch = self.frames.to(scene)[cells[best] // TURN_BINS]
        about_z = torch.zeros(len(angle), 3, dtype=scene.dtype, device=scene.device)
        about_z[:, 2] = angle
        turned = compose(
            model_patch, make_poses(torch.zeros_like(about_z), roma.rotvec_to_unitquat(about_z))
        )
        poses = compose(scene[references[owner[best]]], inverse(turned))
        return poses, peaks[best].to(scene)
