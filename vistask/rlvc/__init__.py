"""RLVC: reinforcement learning of visual classes (interaction database and its presence bits,
class tree or BDD, Q solver, split search, compaction, learner, novelty of percepts for
directed exploration, new percepts by the nearest learned ones, fused structures acting as a
committee), and RLJC: joint classes of percepts and continuous actions (joint tree, learner)."""

from vistask.rlvc.bdd import ClassBDD
from vistask.rlvc.classifier import JointClassifier, VisualClassifier
from vistask.rlvc.committee import Committee
from vistask.rlvc.compaction import acceptable, interchangeable, merge_groups
from vistask.rlvc.copies import vector_copies
from vistask.rlvc.database import (
    InteractionDatabase,
    Transitions,
    check_image_env,
    collect,
    collect_chunks,
    random_policy,
)
from vistask.rlvc.joint_tree import JointTree
from vistask.rlvc.learner import RLVC, StageRecord
from vistask.rlvc.novelty import novelty_bonus, simhash_codes
from vistask.rlvc.presence import PackedPresence
from vistask.rlvc.rljc import RLJC, joint_values
from vistask.rlvc.seen import SeenPercepts
from vistask.rlvc.solver import ClassMDP, estimate_mdp, state_values, td_errors, value_iteration
from vistask.rlvc.split import Split, ThresholdSplit, find_splits, find_threshold_splits
from vistask.rlvc.tree import ClassTree

__all__ = [
    "RLJC",
    "RLVC",
    "ClassBDD",
    "ClassMDP",
    "ClassTree",
    "Committee",
    "InteractionDatabase",
    "JointClassifier",
    "JointTree",
    "PackedPresence",
    "SeenPercepts",
    "Split",
    "StageRecord",
    "ThresholdSplit",
    "Transitions",
    "VisualClassifier",
    "acceptable",
    "check_image_env",
    "collect",
    "collect_chunks",
    "estimate_mdp",
    "find_splits",
    "find_threshold_splits",
    "interchangeable",
    "joint_values",
    "merge_groups",
    "novelty_bonus",
    "random_policy",
    "simhash_codes",
    "state_values",
    "td_errors",
    "value_iteration",
    "vector_copies",
]
