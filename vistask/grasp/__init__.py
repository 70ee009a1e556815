"""Grasp densities: eq. (8), hypothesis densities and trial-and-error learning (paper 3.4-3.5).

Grasps are (..., 7) gripper poses [t, qx, qy, qz, qw] (see ``vistask.se3``); the gripper frame
has its origin between the fingertip pads, +z the approach direction and +x the closing axis.
Grasp densities attached to object models live in the object frame.
"""

from vistask.grasp.density import instance_grasp_density, transform_density
from vistask.grasp.hypothesis import (
    demonstration_density,
    feature_grasps,
    feature_hypothesis_density,
    frames_to_poses,
    scripted_teacher_grasps,
)
from vistask.grasp.importance import (
    Trials,
    empirical_density,
    importance_weights,
    local_success_rates,
    mixture_proposal,
    ranking_auc,
    validated_ranking_width,
)
from vistask.grasp.learning import CycleStats, GraspLearner, evaluate_density, run_trials
from vistask.grasp.reach import (
    TrialRunner,
    Workspace,
    approach_directions,
    draw_reachable,
    reachable,
)

__all__ = [
    "CycleStats",
    "GraspLearner",
    "TrialRunner",
    "Trials",
    "Workspace",
    "approach_directions",
    "demonstration_density",
    "draw_reachable",
    "empirical_density",
    "evaluate_density",
    "feature_grasps",
    "feature_hypothesis_density",
    "frames_to_poses",
    "importance_weights",
    "instance_grasp_density",
    "local_success_rates",
    "mixture_proposal",
    "ranking_auc",
    "reachable",
    "run_trials",
    "scripted_teacher_grasps",
    "transform_density",
    "validated_ranking_width",
]
