"""RLVC: reinforcement learning of visual classes (interaction database, class tree or BDD, Q
solver, split search, compaction, learner)."""

from vistask.rlvc.bdd import ClassBDD
from vistask.rlvc.classifier import VisualClassifier
from vistask.rlvc.compaction import interchangeable, merge_groups
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
from vistask.rlvc.tree import ClassTree

__all__ = [
    "RLVC",
    "ClassBDD",
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
    "interchangeable",
    "merge_groups",
    "random_policy",
    "state_values",
    "td_errors",
    "value_iteration",
    "vector_copies",
]
