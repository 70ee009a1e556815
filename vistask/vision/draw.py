"""Pictures of patches: overlays on the source image."""

from __future__ import annotations

import cv2
import numpy as np
import torch

from vistask.vision.camera import Camera
from vistask.vision.patches import Patches


def draw_patches(
    rgb: torch.Tensor, camera: Camera, patches: Patches, length: float = 0.01, scale: int = 3
) -> np.ndarray:
    """Draw each patch as a short 3-D segment along its direction, projected into the image.

    Segments are green with a red dot at the head, so the direction sign shows.

    Args:
        rgb: (H, W, 3) uint8 image the camera took.
        camera: the camera.
        patches: world-frame patches.
        length: segment length in metres.
        scale: upscaling factor of the output picture.

    Returns:
        (scale * H, scale * W, 3) uint8 RGB picture.
    """
    if scale < 1:
        raise ValueError(f"scale must be >= 1, got {scale}")
    image = cv2.resize(rgb.cpu().numpy(), None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    image = (0.5 * image).astype(np.uint8)  # dim the picture so patches stand out
    p = patches.to("cpu")
    tail, _ = camera.project(p.positions - 0.5 * length * p.directions)
    head, _ = camera.project(p.positions + 0.5 * length * p.directions)
    to_px = lambda x: tuple(int(c) for c in ((x.numpy() + 0.5) * scale).round())  # noqa: E731
    for i in range(len(p)):
        cv2.line(image, to_px(tail[i]), to_px(head[i]), (0, 255, 0), 1, cv2.LINE_AA)
        cv2.circle(image, to_px(head[i]), 1, (255, 0, 0), -1)
    return image
