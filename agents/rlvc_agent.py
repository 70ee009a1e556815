"""RLVCAgent: RLVC on any Gymnasium image environment, with Stable-Baselines3's API."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

from vistask.agents.visual_agent import VisualAgent
from vistask.checks import check_at_least, check_integers
from vistask.features.vocabulary import VOCABULARY_GROUPS
from vistask.parallel import check_not_importing_main
from vistask.rlvc import RLVC, VisualClassifier


class RLVCAgent(VisualAgent):
    """Learns visual classes of an image env by RLVC and acts greedily on them.

    ``learn(total_timesteps)`` collects ``databases`` equal databases of interactions, one
    after the other: the first with uniformly random actions, each later one epsilon-greedily
    on the classes learned so far (``n_envs`` episodes side by side), each added to the earlier
    ones. After each database, RLVC stages run until no class splits (or ``max_stages``): SIFT
    keypoints of every percept are extracted once, matched to a vocabulary of ``n_words``
    visual features (fitted on the first database), and classes are split where a feature
    reduces the variance of the TD errors significantly. A second ``learn`` call continues:
    more databases, more stages.

    An env whose percepts show views side by side says so by a ``panel_widths`` attribute
    (pixels, left to right; the mountain car's road window and gauge): SIFT then runs on each
    view alone, once per distinct view (``SiftExtractor(panel_widths=...)``).

    Episodes end where the env ends them: its terminal states and its own time limit (the
    ``max_episode_steps`` of ``gym.make``); wrap an env without one in ``TimeLimit``.

    Callbacks (SB3's ``BaseCallback``, a list of them, or a function) are called once per
    RLVC stage, where the policy changes: ``CheckpointCallback(save_freq=50)`` saves every 50
    stages, ``EvalCallback(eval_env, eval_freq=50)`` evaluates every 50 stages; returning
    False stops learning. ``num_timesteps`` counts the interactions collected. With
    ``tensorboard_log``, every stage logs ``rlvc/classes``, ``rlvc/selected_features``,
    ``rlvc/mean_abs_td`` and ``rlvc/splits``, with the stage as the step.

    Example:
        >>> import gymnasium as gym, vistask.envs
        >>> env = gym.make("vistask/VisualMaze-v0")
        >>> agent = RLVCAgent(env, seed=0).learn(total_timesteps=40_000)
        >>> action, _ = agent.predict(obs)               # obs: one image, or a batch
        >>> agent.save("rlvc.pt"); agent = RLVCAgent.load("rlvc.pt", env=env)

    Args:
        env: env with (H, W, 3) or (H, W) uint8 image observations and ``Discrete`` actions
            (``None`` only when loading, to predict without an env).
        n_words: vocabulary size: the number of visual features.
        databases: number of equal databases that ``total_timesteps`` is split into.
        alpha: significance level of the split t-tests (Welch).
        min_count: minimum interactions on each side of a split.
        max_stages: stage cap of the stages that follow each database.
        epsilon: exploration rate of the epsilon-greedy databases and of
            ``predict(deterministic=False)``.
        n_envs: episodes collected side by side on the classes, so that features are
            extracted for batches of views.
        max_keypoints: SIFT keeps the strongest keypoints of each percept (0: all).
        contrast_threshold: SIFT's detection threshold. Below SIFT's usual 0.02, dark and
            smooth views still show keypoints: on one random maze layout, the positions that
            show none fell from 2.3% to 0.7%, and over ten layouts the mean return rose from
            0.84 to 0.88 of the oracle's.
        compounds: make compound features (pairs of parts, coarse groups of words or
            compounds, in a stable spatial relation) for the most aliased classes, taken
            where they split better than the class's word split. Off by default: on the maze
            they leave the mean return as it is (0.940 of the oracle's against 0.939, seeds
            0-4) at 2.3 times the run time; where a relation carries the state (a gauge's
            needle), they are what reads it.
        compaction: hold the classes in a BDD; when the stages of a database end, merge
            classes with close values and interchangeable greedy actions, then drop the
            features whose absence leaves every percept seen a good action (with compounds:
            only where it keeps them among interchangeable classes); splits take a feature
            the classes already test when it does half as well as the best; when ``learn``
            ends, the merged classes are grown again as one decision tree over the features
            they test (``RLVC.regrow``), which classifies unseen views better on place
            navigation and leaves the mountain car's return about as it was (0.868 of the
            oracle's against 0.876 before, 1000 starts, seeds 0-4, SIFT on the whole
            percept). False: a decision tree that only splits, on the best feature.
        compact_every: with ``compaction``, merge every this many stages as well (None:
            only when the stages of a database end).
        compaction_tolerance: merge classes whose values, and the values of their greedy
            actions in each other, differ by at most this share of the range of values.
        structures: with ``compaction``, when ``learn`` ends, learn this many class structures
            in all, the learned one and others on bootstrap samples of its interactions over
            the features it made, and act on the mean of their Q: each structure classes a
            percept, and the agent takes the action of best mean Q over the classes it falls
            in (``RLVC.fuse``). The classes (``classifier``) are then the structures fused into
            one partition instead of regrown: the percepts that all structures class alike
            form cells, merged by the mean of the structures' Q. It costs the others'
            learning, without compound search, spread over the cores by ``vistask.parallel``
            (so a script that makes the agent runs it under ``if __name__ ==
            "__main__":``): 11 on the mountain car (16 vocabulary groups) return 0.940 of the
            oracle's return (seeds 0-4). With SIFT on the car's whole percept, 11 returned
            0.922 (0.908 acting on the fused classes) where one structure (64 groups) returned
            0.871, in 1.15 times its run's time (seed 0, one pair of runs).
        nearest_seen: when ``learn`` ends, keep the tested features of the percepts learned
            on, and give each percept met later the class that most of the learned percepts
            nearest to it (fewest tested features different) are in (``RLVC.remember``), so
            that one feature a new percept shows or lacks by chance does not send it into
            another class. On place navigation's held-out views it lowers the error of the
            greedy action from 24.3% to 22.8% (tree, seeds 0-2); on the maze and the mountain
            car it leaves the return as it is. Off by default: the results reported for the
            other defaults were measured without it. False: the classes' tree (or BDD) alone.
        vocabulary_groups: coarse groups of descriptors that the vocabulary's words are
            fitted in (a vocabulary tree: a descriptor is matched to the words of its 3 nearest
            groups). A word's group is its part in compound features: fewer groups make
            coarser parts, so that a relation between two small details recurs although their
            keypoints fall on many words. 16 on the mountain car (eleven structures, acting on the
            fused classes, SIFT on the whole percept): 0.912 of the oracle's return on 1000
            starts instead of 0.877, 0.908 on the 100 instead of 0.911 (seeds 0-4).
        gamma: discount (default: the env's ``gamma`` attribute if it has one, else 0.99).
        tensorboard_log: folder of TensorBoard runs (None: no logging).
        seed: seeds the episodes, the exploration and the vocabulary.
    """

    learner_class = RLVC

    def __init__(
        self,
        env: gym.Env | None,
        n_words: int = 8192,
        databases: int = 4,
        alpha: float = 0.05,
        min_count: int = 10,
        max_stages: int = 300,
        epsilon: float = 0.1,
        n_envs: int = 128,
        max_keypoints: int = 24,
        contrast_threshold: float = 0.005,
        compounds: bool = False,
        compaction: bool = False,
        compact_every: int | None = None,
        compaction_tolerance: float = 0.02,
        structures: int = 1,
        nearest_seen: bool = False,
        vocabulary_groups: int = VOCABULARY_GROUPS,
        gamma: float | None = None,
        tensorboard_log: str | Path | None = None,
        seed: int = 0,
    ) -> None:
        super().__init__(
            env,
            n_words,
            databases,
            alpha,
            min_count,
            max_stages,
            epsilon,
            n_envs,
            max_keypoints,
            contrast_threshold,
            gamma,
            tensorboard_log,
            seed,
        )
        if compact_every is not None:
            check_integers(compact_every=compact_every)
            check_at_least(1, compact_every=compact_every)
        if not 0 <= compaction_tolerance < 1:
            raise ValueError(
                f"compaction_tolerance must be in [0, 1), got {compaction_tolerance!r}"
            )
        self.compounds = bool(compounds)
        self.compaction, self.compact_every = bool(compaction), compact_every
        self.compaction_tolerance = float(compaction_tolerance)
        check_integers(structures=structures)
        check_at_least(1, structures=structures)
        if structures > 1 and not compaction:
            raise ValueError(
                f"structures={structures} fuses class structures by compaction: pass "
                "compaction=True, or structures=1"
            )
        if structures > 1 and nearest_seen:
            raise ValueError(
                f"structures={structures} acts on the structures' classes of each percept, "
                "nearest_seen on the classes of the nearest percepts learned on: pass one"
            )
        if structures > 1:  # at once, not when learning ends and the structures start
            check_not_importing_main(f"RLVCAgent(structures={structures})")
        self.structures = int(structures)
        self.nearest_seen = bool(nearest_seen)
        check_integers(vocabulary_groups=vocabulary_groups)
        check_at_least(1, vocabulary_groups=vocabulary_groups)
        self.vocabulary_groups = int(vocabulary_groups)

    @property
    def rlvc(self) -> RLVC | None:
        """The learner: classes, Q, stage history."""
        return self.learner

    def _new_learner(self) -> RLVC:
        return RLVC(
            self.extractor.n_features,
            int(self.action_space.n),
            self.gamma,
            self.alpha,
            self.min_count,
            use_compounds=self.compounds,
            compaction=self.compaction,
            compact_every=self.compact_every,
            compaction_tolerance=self.compaction_tolerance,
        )

    def _greedy(self, presence: torch.Tensor) -> np.ndarray:
        return self.rlvc.greedy(presence).numpy()

    def _explore(self, presence: torch.Tensor, rng: np.random.Generator) -> np.ndarray:
        """(N,) actions: greedy on the classes, uniformly random with probability epsilon."""
        greedy = self._greedy(presence)
        explore = rng.random(len(greedy)) < self.epsilon
        return np.where(explore, rng.integers(self.rlvc.n_actions, size=len(greedy)), greedy)

    def _end_databases(self) -> None:
        if self.structures > 1:
            self.rlvc.fuse(self.database, self.structures, self.seed)
        elif self.compaction:
            self.rlvc.regrow(self.database)
        if self.nearest_seen:
            self.rlvc.remember(self.database)

    def _extra_params(self) -> dict:
        return {
            "compounds": self.compounds,
            "compaction": self.compaction,
            "compact_every": self.compact_every,
            "compaction_tolerance": self.compaction_tolerance,
            "structures": self.structures,
            "nearest_seen": self.nearest_seen,
            "vocabulary_groups": self.vocabulary_groups,
        }

    @property
    def classifier(self) -> VisualClassifier:
        """Image -> visual class (for ``vistask.wrappers.VisualClasses``)."""
        self._check_learned()
        rlvc = self.rlvc
        return VisualClassifier(self.extractor, rlvc.structure, rlvc.compounds, rlvc.seen)
