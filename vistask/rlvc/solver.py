"""Q over visual classes: estimate the class MDP from counts and solve it by value iteration.

Model-based Q is deterministic and fast; Q-learning sweeps over the same database converge to
the same fixed point.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from vistask.checks import checked


@checked
@dataclass
class ClassMDP:
    """Estimated finite MDP over visual classes.

    Attributes:
        counts: (S, A) visits n(s, a).
        rewards: (S, A) mean reward R^(s, a) (0 where unvisited).
        transitions: sparse (S, A, S) T^(s, a, s') = n(s, a, s') / n(s, a) over non-terminal
            successors: the probability mass of terminal successors is missing, so that they
            bootstrap nothing. Sparse because each interaction adds at most one entry: a dense
            table is S x A x S (32 MB at a thousand classes, rebuilt every stage).
    """

    counts: torch.Tensor
    rewards: torch.Tensor
    transitions: torch.Tensor


@checked
def estimate_mdp(
    states: torch.Tensor,
    actions: torch.Tensor,
    rewards: torch.Tensor,
    next_states: torch.Tensor,
    terminal: torch.Tensor,
    n_states: int,
    n_actions: int,
) -> ClassMDP:
    """Count-based MDP estimate from (N,) tensors of interactions mapped to classes."""
    if len(states) == 0:
        raise ValueError("cannot estimate an MDP from zero interactions")
    if actions.min() < 0 or actions.max() >= n_actions:
        raise ValueError(f"action ids must lie in 0..{n_actions - 1}")
    sa = states * n_actions + actions
    counts = torch.bincount(sa, minlength=n_states * n_actions).double()
    reward_sum = torch.zeros(n_states * n_actions, dtype=torch.float64).index_add_(
        0, sa, rewards.double()
    )
    live = ~terminal
    sas, next_counts = torch.unique(sa[live] * n_states + next_states[live], return_counts=True)
    origin, successor = sas // n_states, sas % n_states
    safe = counts.clamp_min(1)
    transitions = torch.sparse_coo_tensor(
        torch.stack([origin // n_actions, origin % n_actions, successor]),
        next_counts.double() / safe[origin],
        (n_states, n_actions, n_states),
        is_coalesced=True,  # torch.unique sorted the (s, a, s') keys
        check_invariants=False,
    )
    return ClassMDP(
        counts=counts.view(n_states, n_actions),
        rewards=(reward_sum / safe).view(n_states, n_actions),
        transitions=transitions,
    )


@checked
def value_iteration(
    mdp: ClassMDP, gamma: float, tol: float = 1e-8, max_iters: int = 10_000
) -> torch.Tensor:
    """Solve the estimated MDP. Returns Q (S, A); unvisited (s, a) get -inf so that greedy
    choices and max_a' Q(s', a') only consider actions seen in the data (V = 0 for a class
    with no visited action)."""
    if not 0 <= gamma < 1:
        raise ValueError(f"gamma must be in [0, 1), got {gamma}")
    visited = mdp.counts > 0
    n_states, n_actions = mdp.counts.shape
    state, action, successor = mdp.transitions.indices()
    from vistask.rlvc.kernels import value_iteration as iterate  # numba, on first use

    q = iterate(
        (state * n_actions + action).numpy(),
        successor.numpy(),
        mdp.transitions.values().double().numpy(),
        mdp.rewards.reshape(-1).double().numpy(),
        visited.reshape(-1).numpy(),
        float(gamma),
        float(tol),
        int(max_iters),
        n_actions,
    )
    return torch.from_numpy(q).view(n_states, n_actions).masked_fill(~visited, -torch.inf)


@checked
def state_values(q: torch.Tensor) -> torch.Tensor:
    """V(s) = max_a Q(s, a), 0 for classes with no visited action. q (S, A) -> (S,)."""
    v = q.max(dim=1).values
    return torch.where(torch.isfinite(v), v, torch.zeros_like(v))


@checked
def td_errors(
    q: torch.Tensor,
    states: torch.Tensor,
    actions: torch.Tensor,
    rewards: torch.Tensor,
    next_states: torch.Tensor,
    terminal: torch.Tensor,
    gamma: float,
) -> torch.Tensor:
    """Δ_t = r + γ max_a' Q(s'_t, a') − Q(s_t, a_t), no bootstrap when terminal. (N,) float64."""
    bootstrap = torch.where(terminal, 0.0, state_values(q)[next_states])
    return rewards.double() + gamma * bootstrap - q[states, actions]
