"""Hierarchical object models and pose estimation by NBP (paper Sect. 3.2-3.3).

- ``model``: ``ObjectModel`` (primitive features = appearance classes of patches,
  meta-features, SE(3) compatibility potentials; save/load; optional grasp density).
- ``nbp``: nonparametric belief propagation over the model's tree (``infer``).
- ``registration``: Open3D FPFH + RANSAC + ICP baseline.
- ``evaluate``: the benchmark on robosuite tabletop scenes shared by the scripts.
"""

from vistask.objects.evaluate import (
    CONDITIONS,
    DEFAULT_CAMERAS,
    BenchConfig,
    Condition,
    draw_estimate,
    learn_model,
    make_test_scene,
    markdown_table,
    run_benchmark,
    scene_patches,
    summarize,
    visible_fraction,
    write_results,
)
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
    "CONDITIONS",
    "DEFAULT_CAMERAS",
    "MIN_PATCHES_PER_CLASS",
    "BenchConfig",
    "Condition",
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
    "draw_estimate",
    "estimate_pose_open3d",
    "infer",
    "learn_model",
    "make_test_scene",
    "markdown_table",
    "multiply",
    "push_up",
    "register",
    "run_benchmark",
    "scene_evidence",
    "scene_patches",
    "summarize",
    "top_down",
    "visible_fraction",
    "write_results",
]
