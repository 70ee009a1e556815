"""RLVCAgent: RLVC on any Gymnasium image environment, with Stable-Baselines3's API."""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

from vistask.agents.visual_agent import MAX_BLOCKED, VisualAgent
from vistask.checks import check_at_least, check_bools, check_integers, checked
from vistask.features.vocabulary import VOCABULARY_GROUPS
from vistask.parallel import check_not_importing_main
from vistask.rlvc import RLVC, VisualClassifier, novelty_bonus

# What min_effect="auto" means on enlarged views (see ``RLVCAgent.split_margin``); views as
# they are split on any significant difference.
ENLARGED_MIN_EFFECT = 0.01


@checked
@dataclass(frozen=True)
class Compaction:
    """How ``RLVCAgent(compaction=...)`` merges classes (paper section 2.5.2);
    ``compaction=True`` (the default) takes these defaults.

    Args:
        tolerance: merge classes whose values, and the values of their greedy actions in each
            other, differ by at most this share of the range of values (in [0, 1), default
            0.02).
        every: with ``during_learning``, also merge every this many stages (>= 1; None, the
            default: only after each database's stages).
        structures: with ``during_learning``, when ``learn`` ends, learn this many class
            structures in all (the learned one and others on bootstrap samples of its
            interactions) and act on the mean of their Q (>= 1, default 1). The structures
            learn on the cores side by side, so a script that makes the agent runs under
            ``if __name__ == "__main__":``.
        during_learning: hold the classes in a BDD while learning, merge them after each
            database's stages and grow the merged classes again as one decision tree when
            ``learn`` ends (the paper's compaction); False (the default): learn a tree that
            only splits, and merge its classes once, when ``learn`` ends, each percept going
            down the tree's tests to its merged class (``RLVC.merge``).

    Example:
        >>> agent = RLVCAgent(env, compaction=Compaction(tolerance=0.01))
        >>> agent = RLVCAgent(
        ...     env, compaction=Compaction(tolerance=0.01, during_learning=True, structures=11)
        ... )
    """

    tolerance: float = 0.02
    every: int | None = None
    structures: int = 1
    during_learning: bool = False

    def __post_init__(self) -> None:
        if isinstance(self.tolerance, bool) or not 0 <= self.tolerance < 1:
            raise ValueError(f"Compaction: tolerance must be in [0, 1), got {self.tolerance!r}")
        if self.every is not None:
            check_integers(every=self.every)
            check_at_least(1, every=self.every)
        check_integers(structures=self.structures)
        check_at_least(1, structures=self.structures)
        check_bools(during_learning=self.during_learning)
        if not self.during_learning and (self.every is not None or self.structures > 1):
            raise ValueError(
                "Compaction: every and structures act on the classes held in a BDD while "
                "learning: set during_learning=True"
            )


@checked
class RLVCAgent(VisualAgent):
    """Learns visual classes of an image env by RLVC and acts greedily on them.

    ``learn(total_timesteps)`` collects ``databases`` equal databases of interactions, the
    first with uniformly random actions, each later one epsilon-greedily on the classes
    learned so far, each added to the earlier ones. While the rewards met are too few for a
    split (``split_count``), the classes that collect a database learn on the env's rewards
    plus a bonus for reaching percepts rarely met (``novelty``), so that the collection
    explores where the agent knows least; the classes that act learn on the env's rewards.
    After each database, RLVC stages run until no class splits (or ``max_stages``): classes
    are split where the presence of a visual feature (a word of a SIFT vocabulary fitted on
    the first database) reduces the variance of the TD errors significantly. When learning
    ends, classes whose values and greedy actions are interchangeable merge (``compaction``).
    A second ``learn`` call continues from what was learned.

    Episodes end where the env ends them (terminal states, its time limit), and an exploring
    one also after ``max_blocked`` unchanged views in a row. An env whose percepts show views
    side by side gives their widths in a ``panel_widths`` attribute: SIFT then runs on each
    view alone. Callbacks (SB3's ``BaseCallback``, a list, or a function)
    are called once per stage; returning False stops learning. With ``tensorboard_log``, every
    stage logs ``rlvc/classes``, ``rlvc/selected_features``, ``rlvc/mean_abs_td``,
    ``rlvc/splits`` and ``rollout/ep_rew_mean``, with the stage as the step.

    Example:
        >>> import gymnasium as gym, vistask.envs
        >>> env = gym.make("vistask/VisualMaze-v0")
        >>> agent = RLVCAgent(env, seed=0).learn(total_timesteps=40_000)
        >>> action, _ = agent.predict(obs)               # obs: one image, or a batch
        >>> agent.save("rlvc.pt"); agent = RLVCAgent.load("rlvc.pt", env=env)

    Args:
        env: env with (H, W, 3) or (H, W) uint8 image observations and ``Discrete`` actions
            (``None`` only when loading, to predict without an env).
        n_words: visual features: words of the SIFT vocabulary (>= 2, default 8192).
        databases: equal databases that ``total_timesteps`` is split into (>= 1, default 4).
        alpha: significance level of the Welch t-test that accepts a split (in (0, 1),
            default 0.05).
        min_count: interactions needed on each side of a split (>= 2), or ``"auto"`` (the
            default): 5 where SIFT sees the views enlarged (``enlarge``), else 10
            (``split_count`` holds the number in use).
        min_effect: a split must also show TD errors whose means differ by more than this
            share of the range of the class values, so that more interactions do not split
            the classes ever finer (in [0, 1); 0: any significant difference), or ``"auto"``
            (the default): 0.01 where SIFT sees the views enlarged (``enlarge``), else 0
            (``split_margin`` holds the share in use).
        max_stages: stage cap of the stages that follow each database (>= 1, default 300).
        epsilon: exploration rate of the epsilon-greedy databases and of
            ``predict(deterministic=False)`` (in [0, 1], default 0.2).
        n_envs: episodes collected side by side on the classes, on copies of the env made
            again by ``gym.make`` from its spec (settings changed after ``gym.make`` do
            not reach them) or deep-copied (>= 1, default 128).
        max_blocked: an exploring episode (databases after the first) also ends after this
            many steps in a row that leave the view unchanged, so that a policy stuck against
            a wall does not fill the database (0: only where the env ends it, for envs whose
            view can stay the same while their state changes, such as a wait action or a
            blank stretch; >= 0, default 2).
        max_keypoints: strongest SIFT keypoints kept per percept (0: all; default 24).
        contrast_threshold: SIFT's detection threshold (> 0, default 0.005: low, so that dark
            and smooth views still show keypoints).
        enlarge: SIFT runs on each view enlarged this many times, keeping the keypoints whose
            descriptor lies inside the view (``SiftExtractor``'s ``enlarge``; >= 1), or
            ``"auto"`` (the default): 2 where the views are under 56 pixels on a side and
            keep at least as many keypoints enlarged (``choose_enlarge``, on the first
            database's views), else 1.
        compounds: make compound features (two features in a stable spatial relation) for
            the most aliased classes where they split better than a single feature
            (default False).
        compaction: when ``learn`` ends, merge classes with close values and interchangeable
            greedy actions. True (the default) takes ``Compaction()``'s settings; a
            ``Compaction`` sets them (also to merge during learning); False: the classes of
            the tree that only splits.
        nearest_seen: when ``learn`` ends, keep the tested features of the percepts learned
            on; a percept met later takes the class most of its nearest learned percepts are
            in (default False; not with ``structures`` > 1).
        vocabulary_groups: coarse groups of the vocabulary tree; a word's group is its part
            in compound features, so fewer groups make coarser parts (>= 1, default 64; at
            most n_words are used).
        novelty: weight of the novelty bonus that the classes collecting the next database
            learn on while fewer than ``split_count`` interactions were rewarded, a share of
            the largest reward met (1 before any) (>= 0, default 0.01; 0: epsilon-greedy on
            the env's rewards only).
        gamma: discount in [0, 1) (default: the env's ``gamma`` attribute, else 0.99).
        tensorboard_log: folder of TensorBoard runs (None, the default: no logging).
        seed: seeds the episodes, the exploration and the vocabulary (default 0).
    """

    learner_class = RLVC

    def __init__(
        self,
        env: gym.Env | None,
        n_words: int = 8192,
        databases: int = 4,
        alpha: float = 0.05,
        min_count: int | str = "auto",
        min_effect: float | str = "auto",
        max_stages: int = 300,
        epsilon: float = 0.2,
        n_envs: int = 128,
        max_blocked: int = MAX_BLOCKED,
        max_keypoints: int = 24,
        contrast_threshold: float = 0.005,
        enlarge: int | str = "auto",
        compounds: bool = False,
        compaction: bool | Compaction = True,
        nearest_seen: bool = False,
        vocabulary_groups: int = VOCABULARY_GROUPS,
        novelty: float = 0.01,
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
            max_blocked,
            enlarge,
        )
        check_bools(compounds=compounds, nearest_seen=nearest_seen)
        if min_effect != "auto" and (isinstance(min_effect, str) or not 0 <= min_effect < 1):
            raise ValueError(f"min_effect must be 'auto' or in [0, 1), got {min_effect!r}")
        self.min_effect = min_effect if isinstance(min_effect, str) else float(min_effect)
        if not isinstance(compaction, Compaction):
            check_bools(compaction=compaction)
            compaction = Compaction() if compaction else None
        self.compounds, self.nearest_seen = bool(compounds), bool(nearest_seen)
        self.compaction: Compaction | None = compaction
        if self.structures > 1 and nearest_seen:
            raise ValueError(
                f"Compaction(structures={self.structures}) acts on the structures' classes of "
                "each percept, nearest_seen on the classes of the nearest percepts learned on: "
                "pass one"
            )
        if self.structures > 1:  # at once, not when learning ends and the structures start
            check_not_importing_main(
                f"RLVCAgent(compaction=Compaction(structures={self.structures}))"
            )
        check_integers(vocabulary_groups=vocabulary_groups)
        check_at_least(1, vocabulary_groups=vocabulary_groups)
        self.vocabulary_groups = int(vocabulary_groups)
        if not 0 <= novelty < math.inf:
            raise ValueError(f"novelty must be finite and >= 0, got {novelty!r}")
        self.novelty = float(novelty)

    @property
    def structures(self) -> int:
        """Class structures the agent acts on when ``learn`` ends (1 without compaction)."""
        return self.compaction.structures if self.compaction else 1

    @property
    def split_margin(self) -> float:
        """Share of the range of the class values a split's TD errors must differ by:
        ``min_effect``, or for ``"auto"`` ``ENLARGED_MIN_EFFECT`` where the vocabulary sees
        its views enlarged, else 0."""
        if self.min_effect != "auto":
            return self.min_effect
        return ENLARGED_MIN_EFFECT if self.enlarged else 0.0

    @property
    def rlvc(self) -> RLVC | None:
        """The learner: classes, Q, stage history."""
        return self.learner

    def _new_learner(self) -> RLVC:
        during = self.compaction is not None and self.compaction.during_learning
        settings = self.compaction if during else Compaction()  # the learner's, if it merges
        return RLVC(
            self.extractor.n_features,
            int(self.action_space.n),
            self.gamma,
            self.alpha,
            self.split_count,
            use_compounds=self.compounds,
            compaction=during,
            compact_every=settings.every,
            compaction_tolerance=settings.tolerance,
            min_effect=self.split_margin,
        )

    def _greedy(self, presence: torch.Tensor) -> np.ndarray:
        return self.rlvc.greedy(presence).numpy()

    def _explore(self, presence: torch.Tensor, rng: np.random.Generator) -> np.ndarray:
        """(N,) actions: greedy on the classes, uniformly random with probability epsilon."""
        greedy = self._greedy(presence)
        explore = rng.random(len(greedy)) < self.epsilon
        return np.where(explore, rng.integers(self.rlvc.n_actions, size=len(greedy)), greedy)

    @contextmanager
    def _exploring(self, to_collect: int) -> Iterator[None]:
        """While the database holds fewer rewarded interactions than a split needs on one side
        (``split_count``), the classes that collect the next database learn on the env's
        rewards plus the novelty bonus of each interaction's successor (``novelty_bonus``),
        scaled by ``novelty`` and the largest reward met (1 before any): the collection heads
        for percepts rarely met. Otherwise, and for the classes that act when learning ends,
        the env's rewards alone."""
        db = self.database
        if not self.novelty or to_collect == 0 or self.rewards_seen >= self.split_count:
            yield
            return
        rewards = db.rewards
        scale = self.novelty * (float(rewards.abs().max()) or 1.0)
        db.rewards = rewards + scale * novelty_bonus(db.presence, db.next_obs, seed=self.seed)
        try:
            yield
        finally:
            db.rewards = rewards

    def _end_databases(self) -> None:
        if self.structures > 1:
            self.rlvc.fuse(self.database, self.structures, self.seed)
        elif self.compaction is not None:
            if self.compaction.during_learning:
                self.rlvc.regrow(self.database)
            else:
                self.rlvc.merge(self.database, self.compaction.tolerance)
        if self.nearest_seen:
            self.rlvc.remember(self.database)

    def _extra_params(self) -> dict:
        return {
            "compounds": self.compounds,
            "compaction": None if self.compaction is None else asdict(self.compaction),
            "nearest_seen": self.nearest_seen,
            "vocabulary_groups": self.vocabulary_groups,
            "novelty": self.novelty,
            "min_effect": self.min_effect,
        }

    @classmethod
    def _params_from_state(cls, params: dict) -> dict:
        """Saved settings as constructor arguments; files that kept compaction's settings
        beside a bool give them as a ``Compaction``; files without ``novelty`` or
        ``min_effect`` learned without them, and files whose compaction does not say when
        it merged merged during learning."""
        params = {"novelty": 0.0, "min_effect": 0.0, **super()._params_from_state(params)}
        legacy = {
            k: params.pop(k)
            for k in ("compact_every", "compaction_tolerance", "structures")
            if k in params
        }
        compaction = params.get("compaction")
        if isinstance(compaction, dict):
            params["compaction"] = Compaction(**{"during_learning": True, **compaction})
        elif compaction:
            names = {"compaction_tolerance": "tolerance", "compact_every": "every"}
            settings = {names.get(k, k): v for k, v in legacy.items()}
            params["compaction"] = Compaction(during_learning=True, **settings)
        else:
            params["compaction"] = False
        return params

    @property
    def classifier(self) -> VisualClassifier:
        """Image -> visual class (for ``vistask.wrappers.VisualClasses``)."""
        self._check_learned()
        rlvc = self.rlvc
        return VisualClassifier(self.extractor, rlvc.structure, rlvc.compounds, rlvc.seen)
