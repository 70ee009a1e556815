"""Where the arm can grasp: the runner of trials, the workspace, and grasps drawn from a
density until they are in reach."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import roma
import torch

from vistask.checks import check_at_least, checked
from vistask.se3 import SE3KDE, check_poses, compose


@checked
class TrialRunner(Protocol):
    """Executes batches of grasp trials (one per parallel environment)."""

    num_envs: int

    def reset(self, seeds: Sequence[int]) -> torch.Tensor:
        """Start ``num_envs`` trials; returns the (B, 7) world object poses to act on."""
        ...

    def execute(self, grasps: torch.Tensor) -> tuple[torch.Tensor, dict[str, Any]]:
        """Execute (B, 7) world grasps; returns (B,) bool successes and (B,) diagnostics."""
        ...


@checked
@dataclass(frozen=True)
class Workspace:
    """A geometric reachability filter for world-frame grasps (a cheap stand-in for IK).

    Attributes:
        floor_z: height of the support surface; the gripper origin and its open fingertips
            must stay above ``floor_z + clearance``, the pre-grasp pose above
            ``floor_z + 2 clearance``.
        base: (3,) robot base position.
        reach: (min, max) horizontal-plus-vertical distance from the base (metres).
        max_approach_up: largest upward component of the approach direction (no grasps
            from below).
        max_approach_back: largest horizontal component of the approach direction pointing
            back at the base (the arm cannot reach around the object).
        max_approach_out: largest horizontal component of the approach direction pointing
            away from the base (the hand cannot fold back between the base and the object).
        pregrasp_distance: back-off along the approach axis before the approach (metres).
        clearance: margin above the floor (metres).
        opening: distance between the open fingertips (metres), centred on the gripper
            origin along its closing axis (+x); both must stay ``clearance`` above the floor
            too (0: the fingers are not checked).
    """

    floor_z: float
    base: tuple[float, float, float]
    reach: tuple[float, float] = (0.3, 0.85)
    max_approach_up: float = 0.2
    max_approach_back: float = 0.5
    max_approach_out: float = 1.0
    pregrasp_distance: float = 0.08
    clearance: float = 0.005
    opening: float = 0.0

    def __post_init__(self) -> None:
        if not 0 <= self.reach[0] < self.reach[1]:
            raise ValueError(f"reach must be (near, far) with 0 <= near < far, got {self.reach}")
        check_at_least(
            0,
            pregrasp_distance=self.pregrasp_distance,
            clearance=self.clearance,
            opening=self.opening,
        )


@checked
def approach_directions(grasps: torch.Tensor) -> torch.Tensor:
    """(..., 7) grasp poses -> (..., 3) approach directions (the gripper's +z)."""
    return roma.unitquat_to_rotmat(grasps[..., 3:])[..., :, 2]


@checked
def reachable(grasps: torch.Tensor, workspace: Workspace) -> torch.Tensor:
    """(N, 7) world grasps -> (N,) bool: passes the workspace's reachability tests."""
    grasps = check_poses(grasps, "grasps", batched=True)
    t, R = grasps[:, :3], roma.unitquat_to_rotmat(grasps[:, 3:])
    z = R[:, :, 2]  # the approach direction
    lowest_finger = t[:, 2] - 0.5 * workspace.opening * R[:, 2, 0].abs()  # R[:, 2, 0]: closing z
    base = torch.tensor(workspace.base, dtype=t.dtype, device=t.device)
    pre = t - workspace.pregrasp_distance * z
    dist = (t - base).norm(dim=-1)
    outward = torch.nn.functional.normalize((t - base)[:, :2], dim=-1)
    out = (z[:, :2] * outward).sum(-1)
    return (
        (lowest_finger >= workspace.floor_z + workspace.clearance)
        & (pre[:, 2] >= workspace.floor_z + 2 * workspace.clearance)
        & (dist >= workspace.reach[0])
        & (dist <= workspace.reach[1])
        & (z[:, 2] <= workspace.max_approach_up)
        & (-out <= workspace.max_approach_back)
        & (out <= workspace.max_approach_out)
    )


@checked
def draw_reachable(
    density: SE3KDE,
    object_poses: torch.Tensor,
    workspace: Workspace | None = None,
    generator: torch.Generator | None = None,
    max_draws: int = 4096,
    candidates: int = 1,
    score: Callable[[torch.Tensor], torch.Tensor] | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """One reachable grasp per object pose, drawn from an object-frame density.

    Each object gets the first reachable grasp among ``max_draws`` draws: a draw from the
    density restricted to the reachable grasps. Objects left without one keep their first
    draw. The bottle's hypothesis density reaches 1.7% of its draws in every placement, so
    50 draws found none in about 4 placements of 10. With ``candidates`` > 1, that many
    reachable grasps are drawn per object and the one that ``score`` rates highest is kept
    (by default the likeliest, where the density is highest): the usual way to *use* a grasp
    density (pick a good grasp among the feasible ones) rather than to explore it.

    Args:
        density: object-frame grasp density.
        object_poses: (B, 7) world poses of the objects.
        workspace: reachability filter (None: everything is reachable).
        generator: random generator on the density's device.
        max_draws: draws per object and candidate at most.
        candidates: reachable draws per object to choose from (1: plain sampling).
        score: (M, 7) object-frame grasps -> (M,) ratings of the candidates (default: the
            density's values), e.g. ``GraspLearner.success_rates``.

    Returns:
        (B, 7) object-frame grasps, (B, 7) world grasps, (B,) bool reachable.
    """
    check_at_least(1, candidates=candidates, max_draws=max_draws)
    if score is not None and candidates == 1:
        raise ValueError("score acts only with candidates > 1: it chooses among them")
    local, world, ok = draw_candidates(
        density, object_poses, workspace, generator, max_draws, candidates
    )
    if candidates == 1:
        return local[0], world[0], ok[0]
    rating = (density.evaluate if score is None else score)(local.reshape(-1, 7))
    rating = torch.where(ok, rating.reshape(ok.shape), torch.full_like(ok, -1.0, dtype=local.dtype))
    best = rating.argmax(dim=0)
    pick = torch.arange(len(object_poses))
    return local[best, pick], world[best, pick], ok[best, pick]


def draw_candidates(
    density: SE3KDE,
    object_poses: torch.Tensor,
    workspace: Workspace | None = None,
    generator: torch.Generator | None = None,
    max_draws: int = 4096,
    candidates: int = 1,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The candidates ``draw_reachable`` chooses among: ``candidates`` reachable draws per
    object pose, in the order drawn (see ``draw_reachable`` for the arguments).

    Returns:
        (K, B, 7) object-frame grasps, (K, B, 7) world grasps, (K, B) bool reachable.
    """
    check_at_least(1, candidates=candidates, max_draws=max_draws)
    object_poses = check_poses(object_poses, "object_poses", batched=True).to(density.points)
    draws = [
        _draw_reachable_once(density, object_poses, workspace, generator, max_draws)
        for _ in range(candidates)
    ]
    return tuple(torch.stack(parts) for parts in zip(*draws, strict=True))


def _draw_reachable_once(
    density: SE3KDE,
    object_poses: torch.Tensor,
    workspace: Workspace | None,
    generator: torch.Generator | None,
    max_draws: int,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    B = len(object_poses)
    if workspace is None:
        local = density.sample(B, generator)
        return local, compose(object_poses, local), torch.ones(B, dtype=torch.bool)
    local = density.sample(max_draws * B, generator)
    world = compose(object_poses.repeat(max_draws, 1), local)
    hit = reachable(world, workspace)
    first = hit.view(max_draws, B).to(torch.uint8).argmax(dim=0)  # else the first draw
    pick = first * B + torch.arange(B, device=first.device)
    return local[pick], world[pick], hit[pick]
