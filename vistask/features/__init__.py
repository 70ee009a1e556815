"""Image -> visual features: local descriptors at interest points, a learned vocabulary, and
compounds of features in a stable spatial relation."""

from vistask.features.compounds import (
    Compound,
    Occurrences,
    add_compound_occurrences,
    draw_compound,
    propose,
)
from vistask.features.keypoints import (
    Keypoints,
    SiftExtractor,
    check_image,
    check_image_space,
    choose_enlarge,
)
from vistask.features.vocabulary import VisualFeatureExtractor

__all__ = [
    "Compound",
    "Keypoints",
    "Occurrences",
    "SiftExtractor",
    "VisualFeatureExtractor",
    "add_compound_occurrences",
    "check_image",
    "check_image_space",
    "choose_enlarge",
    "draw_compound",
    "propose",
]
