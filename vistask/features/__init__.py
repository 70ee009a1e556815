"""Image -> visual features: local descriptors at interest points and a learned vocabulary."""

from vistask.features.keypoints import Keypoints, SiftExtractor, check_image, check_image_space
from vistask.features.vocabulary import VisualFeatureExtractor

__all__ = [
    "Keypoints",
    "SiftExtractor",
    "VisualFeatureExtractor",
    "check_image",
    "check_image_space",
]
