"""Hierarchical object models and pose estimation by NBP (paper Sect. 3.2-3.3).

- ``model``: ``ObjectModel`` (primitive features = appearance classes of patches,
  meta-features, SE(3) compatibility potentials; save/load; optional grasp density).
- ``nbp``: nonparametric belief propagation over the model's tree (``infer``).
- ``registration``: Open3D FPFH + RANSAC + ICP baseline.
"""

from vistask.objects.model import (
    MIN_PATCHES_PER_CLASS,
    Feature,
    ModelConfig,
    ObjectModel,
    appearance_descriptors,
)
from vistask.objects.nbp import (
    Evidence,
    NBPConfig,
    NBPResult,
    SceneMatch,
    infer,
    multiply,
    push_up,
    scene_evidence,
    top_down,
)
from vistask.objects.registration import (
    RegistrationConfig,
    RegistrationResult,
    estimate_pose_open3d,
    register,
)

__all__ = [
    "MIN_PATCHES_PER_CLASS",
    "Evidence",
    "Feature",
    "ModelConfig",
    "NBPConfig",
    "NBPResult",
    "ObjectModel",
    "RegistrationConfig",
    "RegistrationResult",
    "SceneMatch",
    "appearance_descriptors",
    "estimate_pose_open3d",
    "infer",
    "multiply",
    "push_up",
    "register",
    "scene_evidence",
    "top_down",
]
