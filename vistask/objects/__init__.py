"""Hierarchical object models and pose estimation by NBP (paper Sect. 3.2-3.3).

- ``model``: ``ObjectModel`` (primitive features = appearance classes of patches,
  meta-features, SE(3) compatibility potentials; save/load; optional grasp density).
- ``depth``: pose hypotheses refined and checked against depth images (``DepthCheck``).
- ``nbp``: nonparametric belief propagation over the model's tree (``NBP``); ``messages``:
  its evidence, messages, top-down pass and the scoring of poses against the scene.
- ``registration``: Open3D FPFH + RANSAC + ICP baseline (``Open3DRegistration``).
"""

from vistask.objects.depth import DepthCheck
from vistask.objects.messages import (
    Evidence,
    NBPResult,
    SceneMatch,
    multiply,
    push_up,
    scene_evidence,
    top_down,
)
from vistask.objects.model import (
    MIN_PATCHES_PER_CLASS,
    Feature,
    ObjectModel,
    appearance_descriptors,
)
from vistask.objects.nbp import NBP
from vistask.objects.registration import Open3DRegistration, RegistrationResult

__all__ = [
    "MIN_PATCHES_PER_CLASS",
    "NBP",
    "DepthCheck",
    "Evidence",
    "Feature",
    "NBPResult",
    "ObjectModel",
    "Open3DRegistration",
    "RegistrationResult",
    "SceneMatch",
    "appearance_descriptors",
    "multiply",
    "push_up",
    "scene_evidence",
    "top_down",
]
