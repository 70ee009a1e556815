"""torchrl transforms match the Gymnasium wrappers and pass torchrl's spec checks."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from torchrl.collectors import Collector  # SyncDataCollector before torchrl 0.11
from torchrl.envs import Compose, GymEnv, TransformedEnv
from torchrl.envs.utils import check_env_specs

import vistask.envs  # noqa: F401  (registers the maze)
from vistask.agents import RLVCAgent
from vistask.features.compounds import propose
from vistask.torchrl_transforms import VisualClassTransform, VisualFeatureTransform
from vistask.wrappers import VisualClasses, VisualFeatures

ENV_ID = "vistask/VisualMaze-v0"
# A small maze with big steps and two exits: RLVC finds several classes in seconds.
SMALL = dict(
    obstacles=((0.45, 0.0, 0.55, 0.6),),
    exits=((0.0, 0.0, 0.2, 0.2), (0.8, 0.0, 1.0, 0.2)),
    step=0.2,
)


@pytest.fixture(scope="module")
def agent() -> RLVCAgent:
    agent = RLVCAgent(gym.make(ENV_ID, **SMALL), n_words=128, seed=0).learn(
        2000, progress_bar=False
    )
    assert agent.classifier.n_classes > 1  # else class agreement would be trivial
    return agent


def _env(agent: RLVCAgent) -> TransformedEnv:
    return TransformedEnv(
        GymEnv(ENV_ID, **SMALL),
        Compose(VisualFeatureTransform(agent.extractor), VisualClassTransform(agent.classifier)),
    )


def test_transformed_env_passes_check_env_specs(agent):
    env = _env(agent)
    check_env_specs(env, seed=0)
    spec = env.observation_spec
    assert spec["features"].shape == (agent.extractor.n_features,)
    assert spec["visual_class"].space.n == agent.classifier.n_classes
    reset = env.reset()
    assert reset["features"].dtype == torch.int8 and reset["visual_class"].shape == ()


def test_collector_rollout_matches_gymnasium_wrappers(agent):
    torch.manual_seed(0)
    collector = Collector(lambda: _env(agent), policy=None, frames_per_batch=60, total_frames=60)
    batch = next(iter(collector))
    collector.shutdown()
    pixels = batch["next", "pixels"].numpy()
    classes = batch["next", "visual_class"].numpy()
    features = batch["next", "features"].numpy()
    assert pixels.shape[0] == 60

    classes_wrapper = VisualClasses(gym.make(ENV_ID, **SMALL), agent.classifier)
    features_wrapper = VisualFeatures(gym.make(ENV_ID, **SMALL), agent.extractor)
    expected = [classes_wrapper.observation(image) for image in pixels]
    assert classes.tolist() == expected
    np.testing.assert_array_equal(features, [features_wrapper.observation(p) for p in pixels])
    # The current step's observation was transformed too (on reset as well as on step).
    first = VisualClasses(gym.make(ENV_ID, **SMALL), agent.classifier).observation(
        batch["pixels"][0].numpy()
    )
    assert int(batch["visual_class"][0]) == first
    assert len(set(expected)) > 1  # the rollout visits several classes


def test_transform_rejects_non_images(agent):
    transform = VisualClassTransform(agent.classifier)
    with pytest.raises(ValueError, match="uint8 images"):
        transform._apply_transform(torch.zeros(4, 7))


def test_transforms_refuse_images_of_another_shape_than_learned_on(agent):
    other = GymEnv(ENV_ID, window=48, **SMALL)
    for transform in (
        VisualFeatureTransform(agent.extractor),
        VisualClassTransform(agent.classifier),
    ):
        with pytest.raises(ValueError, match=r"learned on images of shape \(64, 64, 3\)"):
            TransformedEnv(other, transform).rollout(2)
        with pytest.raises(ValueError, match=r"the images under 'pixels' are \(48, 48, 3\)"):
            transform._apply_transform(torch.zeros(2, 48, 48, 3, dtype=torch.uint8))


def test_compounds_follow_the_words_in_the_wrapper_and_the_transform(agent):
    maze = gym.make(ENV_ID, **SMALL)
    images = [maze.reset(seed=s)[0] for s in range(20)]
    compounds = propose(agent.extractor.occurrences(images), min_count=3)[:4]
    assert len(compounds) == 4
    n = agent.extractor.n_features
    wrapper = VisualFeatures(gym.make(ENV_ID, **SMALL), agent.extractor, compounds)
    assert wrapper.observation_space == gym.spaces.MultiBinary(n + 4)
    observed = np.stack([wrapper.observation(image) for image in images])
    words = VisualFeatures(gym.make(ENV_ID, **SMALL), agent.extractor)
    np.testing.assert_array_equal(observed[:, :n], [words.observation(i) for i in images])
    # A candidate's pairs lie within one tolerance cell of its offset: it shows somewhere.
    assert observed[:, n:].any(axis=0).all()

    env = TransformedEnv(
        GymEnv(ENV_ID, **SMALL), VisualFeatureTransform(agent.extractor, compounds=compounds)
    )
    check_env_specs(env, seed=0)
    reset = env.reset()
    assert reset["features"].shape == (n + 4,)
    expected = wrapper.observation(reset["pixels"].numpy())
    np.testing.assert_array_equal(reset["features"].numpy(), expected)


def test_grey_images_go_through_the_transforms_under_the_key_torchrl_keeps_them(agent):
    from torchrl.envs import GymWrapper

    def grey():
        return gym.wrappers.GrayscaleObservation(gym.make(ENV_ID, **SMALL))

    learned = RLVCAgent(grey(), n_words=128, seed=0).learn(2000, progress_bar=False)
    with pytest.raises(KeyError, match=r"no 'pixels' among .*'observation'.*pass in_key="):
        TransformedEnv(GymWrapper(grey()), VisualClassTransform(learned.classifier)).rollout(2)
    env = TransformedEnv(
        GymWrapper(grey()), VisualClassTransform(learned.classifier, in_key="observation")
    )
    check_env_specs(env, seed=0)
    rollout = env.rollout(20)
    wrapper = VisualClasses(grey(), learned.classifier)
    expected = [wrapper.observation(image) for image in rollout["next", "observation"].numpy()]
    assert rollout["next", "visual_class"].tolist() == expected
    with pytest.raises(ValueError, match=r"learned on images of shape \(64, 64\)"):
        VisualClassTransform(learned.classifier, in_key="observation")._apply_transform(
            torch.zeros(2, 48, 48, dtype=torch.uint8)
        )
