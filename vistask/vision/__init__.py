"""3-D oriented appearance patches from RGB-D images (the "ECV-like" front end).

Conventions: OpenCV images and cameras (see ``camera``); poses (..., 7) are
``[tx, ty, tz, qx, qy, qz, qw]`` (roma XYZW), frame -> world.
"""

from vistask.vision.camera import (
    Camera,
    RGBDView,
    backproject,
    depth_buffer_to_metres,
    intrinsics_from_fovy,
    look_at,
    pixel_grid,
    project,
)
from vistask.vision.patches import Patches, PatchExtractor
from vistask.vision.symmetry import Symmetry, estimate_symmetry, pose_error
from vistask.vision.views import object_patch_set, object_surface, view_patches

__all__ = [
    "Camera",
    "PatchExtractor",
    "Patches",
    "RGBDView",
    "Symmetry",
    "backproject",
    "depth_buffer_to_metres",
    "estimate_symmetry",
    "intrinsics_from_fovy",
    "look_at",
    "object_patch_set",
    "object_surface",
    "pixel_grid",
    "pose_error",
    "project",
    "view_patches",
]
