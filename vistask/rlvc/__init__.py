"""RLVC: reinforcement learning of visual classes (interaction database, class tree, Q solver,
split search, learner)."""

from vistask.rlvc.database import (
    InteractionDatabase,
    Transitions,
    check_image_env,
    collect,
    random_policy,
    vector_copies,
)
from vistask.rlvc.learner import RLVC, StageRecord
from vistask.rlvc.solver import ClassMDP, estimate_mdp, state_values, td_errors, value_iteration
from vistask.rlvc.split import Split, find_splits
from vistask.rlvc.tree import ClassTree, VisualClassifier

__all__ = [
    "RLVC",
    "ClassMDP",
    "ClassTree",
    "InteractionDatabase",
    "Split",
    "StageRecord",
    "Transitions",
    "VisualClassifier",
    "check_image_env",
    "collect",
    "estimate_mdp",
    "find_splits",
    "random_policy",
    "state_values",
    "td_errors",
    "value_iteration",
    "vector_copies",
]
