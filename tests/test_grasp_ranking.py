"""Scoring rankings of best-of-K candidates whose outcomes are all known."""

from __future__ import annotations

import torch

from vistask.experiments.grasp_ranking import ranked_success
from vistask.grasp import GraspLearner
from vistask.se3 import SE3KDE, identity_poses


def test_ranked_success_picks_the_reachable_candidate_the_trials_rate_best() -> None:
    """Trials succeed at x = 0 and fail at x = 5 cm. Placement 0: the first candidate lies at
    5 cm and fails, the second at 0 and succeeds; placement 1: the candidate at 0 is out of
    reach (and would succeed), so the ranking must take the one at 5 cm."""
    at = lambda x: torch.tensor([x, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])  # noqa: E731
    flat = SE3KDE(identity_poses(1), torch.ones(1), 1.0, 3.0)
    learner = GraspLearner(flat, sigma_t=0.002, sigma_r=0.05)
    grasps = torch.stack([at(0.0)] * 10 + [at(0.05)] * 10)
    learner.trials.add(grasps, torch.arange(20) < 10, cycle=0)
    learner.proposals.append(flat)
    outcomes = {
        "local": torch.stack([torch.stack([at(0.05), at(0.0)]), torch.stack([at(0.0), at(0.05)])]),
        "ok": torch.tensor([[True, True], [False, True]]),
        "success": torch.tensor([[False, True], [True, False]]),
    }
    result = ranked_success(learner, outcomes, widths=(2.0, 6.0))
    assert result["width 2"] == result["width 6"] == 0.5
    assert result["first"] == 0.5 and result["mean"] == 0.5 and result["any"] == 1.0
    # Before a second cycle validates a ranking, the learner keeps the first reachable one.
    assert result["validated"] == 0.0
    outcomes["ok"][1, 0] = True
    assert ranked_success(learner, outcomes, widths=(6.0,))["width 6"] == 1.0
