"""torchrl transforms: image observation -> visual features, image -> visual class.

The torchrl counterparts of ``vistask.wrappers.VisualFeatures`` and ``VisualClasses``, for a
``torchrl.envs.GymEnv`` whose Box image observation torchrl stores under ``"pixels"`` (RGB) or
``"observation"`` (grey: pass ``in_key="observation"``).

Example:
    >>> from torchrl.envs import GymEnv, TransformedEnv
    >>> agent = RLVCAgent.load("rlvc.pt")
    >>> transform = VisualClassTransform(agent.classifier)
    >>> env = TransformedEnv(GymEnv("vistask/VisualMaze-v0"), transform)
    >>> env.rollout(10)["visual_class"]        # (10,) int64 class ids
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from torchrl.data import Binary, Categorical, Composite, TensorSpec
from torchrl.envs.transforms import Transform

from vistask.checks import checked
from vistask.features import Compound, VisualFeatureExtractor
from vistask.wrappers import Classifier


def _check_images(shape: Sequence[int], dtype: torch.dtype, dims: int, what: str) -> None:
    """Refuse what is not (..., H, W, 3) (``dims`` 3) or grey (..., H, W) (``dims`` 2)
    uint8 images, naming ``what``."""
    if len(shape) < dims or dtype != torch.uint8 or (dims == 3 and shape[-1] != 3):
        image = "(..., H, W, 3)" if dims == 3 else "(..., H, W)"
        raise ValueError(f"{what} needs {image} uint8 images, got {tuple(shape)} {dtype}")


def _images(pixels: torch.Tensor, dims: int) -> tuple[list[np.ndarray], torch.Size]:
    """(..., H, W, 3) (``dims`` 3) or (..., H, W) grey (``dims`` 2) uint8 tensor -> list of
    (H, W, 3) or (H, W) arrays and the leading batch shape."""
    batch = pixels.shape[:-dims]
    flat = pixels.reshape(-1, *pixels.shape[-dims:]).cpu().numpy()
    return list(flat), batch


class _ImageTransform(Transform):
    """Maps ``in_key`` images, RGB or grey as the vocabulary's, to ``out_key`` after every
    step and reset; the spec of ``out_key`` is ``self._spec(device)`` (per observation,
    without batch dims)."""

    def __init__(self, in_key: str, out_key: str) -> None:
        super().__init__(in_keys=[in_key], out_keys=[out_key])

    def _spec(self, device) -> TensorSpec:
        raise NotImplementedError

    def _vocabulary(self) -> VisualFeatureExtractor | None:
        raise NotImplementedError

    def _image_dims(self, shape: tuple) -> int:
        """3 for (H, W, 3) images, 2 for grey (H, W) ones: as the vocabulary was learned on,
        else as ``shape`` (the observation's, batch dims first) ends."""
        vocabulary = self._vocabulary()
        if vocabulary is not None and vocabulary.image_shape is not None:
            return len(vocabulary.image_shape)
        return 3 if shape[-1:] == (3,) else 2

    def _checked_dims(self, shape: Sequence[int], dtype: torch.dtype, what: str) -> int:
        """The image dims (``_image_dims``) of observations of ``shape`` and ``dtype``, which
        are refused, naming ``what``, unless they are images of the vocabulary's shape."""
        dims = self._image_dims(tuple(shape))
        _check_images(shape, dtype, dims, what)
        self._check_shape(tuple(shape[-dims:]))
        return dims

    def _images(self, pixels: torch.Tensor) -> tuple[list[np.ndarray], torch.Size]:
        dims = self._checked_dims(pixels.shape, pixels.dtype, type(self).__name__)
        return _images(pixels, dims)

    def _check_shape(self, shape: tuple) -> None:
        """Refuse images of another shape than the vocabulary was learned on."""
        vocabulary = self._vocabulary()
        if vocabulary is not None:
            images = f"the images under {self.in_keys[0]!r}"
            vocabulary.check_shape(shape, type(self).__name__, images)

    def _check_key(self, keys) -> None:
        """Refuse observations (``keys``) without the images' key, naming theirs."""
        if self.in_keys[0] not in keys:
            # torchrl's GymEnv keeps RGB image observations under "pixels", others (a grey
            # image) under "observation".
            raise KeyError(
                f"{type(self).__name__}: no {self.in_keys[0]!r} among the env's observations "
                f"{sorted(k for k in keys if isinstance(k, str))}: pass in_key= the one of "
                "the images"
            )

    def _call(self, tensordict):
        self._check_key(tensordict.keys())
        return super()._call(tensordict)

    def _reset(self, tensordict, tensordict_reset):
        # Transform._reset passes resets through untouched; the first observation needs it too.
        return self._call(tensordict_reset)

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        key = self.in_keys[0]
        self._check_key(observation_spec.keys())
        image_spec = observation_spec[key]
        what = f"{type(self).__name__} (under {key!r})"
        dims = self._checked_dims(image_spec.shape, image_spec.dtype, what)
        batch = image_spec.shape[:-dims]
        spec = self._spec(image_spec.device)
        observation_spec[self.out_keys[0]] = spec.expand(*batch, *spec.shape)
        return observation_spec


@checked
class VisualFeatureTransform(_ImageTransform):
    """Image -> (F + C,) int8 presence vector of the F visual features (words) and of C
    compound features (``Binary`` spec).

    Args:
        extractor: the visual feature extractor (vocabulary).
        in_key: key of the (..., H, W, 3) or grey (..., H, W) uint8 images (torchrl's
            ``GymEnv`` keeps RGB images under "pixels", grey ones under "observation").
        out_key: key of the (..., F + C) int8 presence vectors.
        compounds: compounds learned on this extractor's words (``RLVC.compounds``).
    """

    def __init__(
        self,
        extractor: VisualFeatureExtractor,
        in_key: str = "pixels",
        out_key: str = "features",
        *,
        compounds: Sequence[Compound] = (),
    ) -> None:
        super().__init__(in_key, out_key)
        self.extractor = extractor
        self.compounds = list(compounds)

    def _spec(self, device) -> TensorSpec:
        n = self.extractor.n_features + len(self.compounds)
        return Binary(n=n, shape=(n,), device=device, dtype=torch.int8)

    def _vocabulary(self) -> VisualFeatureExtractor:
        return self.extractor

    def _apply_transform(self, pixels: torch.Tensor) -> torch.Tensor:
        images, batch = self._images(pixels)
        presence = self.extractor.presence(images, self.compounds).to(torch.int8)
        return presence.reshape(*batch, -1).to(pixels.device)


@checked
class VisualClassTransform(_ImageTransform):
    """Image -> visual class id in ``range(classifier.n_classes)`` (``Categorical`` spec).

    Args:
        classifier: image -> class with ``n_classes`` (``RLVCAgent.classifier``); its batched
            ``classify(images)`` is used when present.
        in_key: key of the (..., H, W, 3) or grey (..., H, W) uint8 images (torchrl's
            ``GymEnv`` keeps RGB images under "pixels", grey ones under "observation").
        out_key: key of the (...,) int64 class ids.
    """

    def __init__(
        self, classifier: Classifier, in_key: str = "pixels", out_key: str = "visual_class"
    ) -> None:
        super().__init__(in_key, out_key)
        self.classifier = classifier

    def _spec(self, device) -> TensorSpec:
        return Categorical(n=self.classifier.n_classes, shape=(), device=device, dtype=torch.int64)

    def _classes(self, images: Sequence[np.ndarray]) -> torch.Tensor:
        if hasattr(self.classifier, "classify"):
            return torch.as_tensor(self.classifier.classify(list(images)), dtype=torch.int64)
        return torch.tensor([int(self.classifier(image)) for image in images], dtype=torch.int64)

    def _vocabulary(self) -> VisualFeatureExtractor | None:
        return getattr(self.classifier, "extractor", None)  # a classifier of vistask's

    def _apply_transform(self, pixels: torch.Tensor) -> torch.Tensor:
        images, batch = self._images(pixels)
        return self._classes(images).reshape(batch).to(pixels.device)
