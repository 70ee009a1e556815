"""What a comparison of RLVC (or RLJC) against baselines runs: methods, budgets, seeds, the
env, and the baselines' settings after rl-zoo3."""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence

import gymnasium as gym

from vistask.checks import check_at_least
from vistask.experiments.tasks import has_oracle
from vistask.rlvc.database import check_image_env

DISCRETE_METHODS = ("rlvc", "rlvc_compounds", "dqn", "ppo", "tabular", "random")
CONTINUOUS_METHODS = ("rljc", "sac", "ppo", "random")
METHODS = tuple(dict.fromkeys(DISCRETE_METHODS + CONTINUOUS_METHODS))
DEFAULT_BUDGETS = (1_000, 2_000, 5_000, 10_000, 20_000, 50_000, 100_000, 200_000, 300_000)
QUICK_BUDGETS = (300, 1_000)
THRESHOLDS = (0.9, 0.75)  # fractions of the oracle's return; 0.9 is the target


# -- configuration ------------------------------------------------------------------------
class Comparison:
    """What a comparison runs: methods, budgets, seeds, the env and the baselines' settings.

    Example:
        >>> summary = compare(Comparison(methods=("rlvc", "tabular"), seeds=3), out="runs/c")

    Args:
        env_id, env_kwargs: the environment (``gym.make`` arguments), of image observations.
            Methods are scored against the oracle of the envs that have one
            (``tasks.task_for``), and by their mean episode reward on any other
            (``tasks.EpisodeTask``).
        methods: subset of ``DISCRETE_METHODS`` for an env with discrete actions, of
            ``CONTINUOUS_METHODS`` for continuous ones (None: all of them; "tabular" only on
            an env with an oracle).
        budgets: increasing interaction budgets at which every method is evaluated.
        seeds: number of seeds (seed k uses ``seed0 + k``).
        seed0: first seed.
        eval_starts: number of fixed evaluation start positions (episodes on an env without
            an oracle).
        grid: cells per dimension of the tabular baseline's true-state grid (None: as many
            cells as RLVC's classes at the largest budget, the paper's "equivalent number of
            states"; RLVC then runs first).
        dqn_kwargs, ppo_kwargs, sac_kwargs: extra SB3 constructor arguments (override the
            defaults, which are rl-zoo3's tuned settings for Atari images where it has them:
            see ``sb3_kwargs``).
        ppo_envs: environments PPO collects from side by side (rl-zoo3's Atari setting: 8).
        device: torch device of the SB3 networks.
    """

    def __init__(
        self,
        env_id: str = "vistask/VisualMaze-v0",
        env_kwargs: dict | None = None,
        methods: Sequence[str] | None = None,
        budgets: Sequence[int] = DEFAULT_BUDGETS,
        seeds: int = 5,
        seed0: int = 0,
        eval_starts: int = 100,
        grid: int | None = 10,
        dqn_kwargs: dict | None = None,
        ppo_kwargs: dict | None = None,
        sac_kwargs: dict | None = None,
        ppo_envs: int = 8,
        device: str = "cpu",
    ) -> None:
        env = gym.make(env_id, **(env_kwargs or {}))
        continuous = isinstance(env.action_space, gym.spaces.Box)
        check_image_env(env, continuous)
        oracle = has_oracle(env)
        env.close()
        allowed = CONTINUOUS_METHODS if continuous else DISCRETE_METHODS
        if not oracle:  # the tabular baseline learns on the true state, which only they give
            allowed = tuple(m for m in allowed if m != "tabular")
        methods = allowed if methods is None else tuple(methods)
        budgets = tuple(int(b) for b in budgets)
        if "tabular" in methods and not oracle:
            raise ValueError(
                f"the tabular baseline learns on the true state, which {env_id} does not give "
                "(only the envs with an oracle do): leave tabular out"
            )
        unknown = set(methods) - set(allowed)
        if unknown or not methods:
            kind = "continuous" if continuous else "discrete"
            raise ValueError(
                f"{env_id} has {kind} actions: methods must be a non-empty subset of "
                f"{allowed}, got {methods}"
            )
        if not budgets or min(budgets) < 1 or list(budgets) != sorted(set(budgets)):
            raise ValueError(f"budgets must be strictly increasing positive ints, got {budgets}")
        check_at_least(1, seeds=seeds, eval_starts=eval_starts, ppo_envs=ppo_envs)
        if grid is not None:
            check_at_least(1, grid=grid)
        elif "tabular" in methods and not any(m.startswith("rlvc") for m in methods):
            raise ValueError(
                "grid=None sizes the tabular grid by RLVC's classes: add an rlvc method"
            )
        self.env_id, self.env_kwargs = env_id, dict(env_kwargs or {})
        self.methods, self.budgets, self.seeds, self.seed0 = methods, budgets, seeds, seed0
        self.eval_starts, self.grid, self.device = eval_starts, grid, device
        self.dqn_kwargs, self.ppo_kwargs = dict(dqn_kwargs or {}), dict(ppo_kwargs or {})
        self.sac_kwargs = dict(sac_kwargs or {})
        self.ppo_envs = ppo_envs
        self._warn_untrained()

    def _warn_untrained(self) -> None:
        """Warn where a budget comes before an SB3 baseline's first update: its policy is
        scored untrained there."""
        for method in ("dqn", "ppo", "sac"):
            if method not in self.methods:
                continue
            kwargs = self.sb3_kwargs(method)
            if method == "ppo":
                first = kwargs["n_steps"] * self.ppo_envs
            else:
                first = kwargs.get("learning_starts", 100) + kwargs.get("train_freq", 1)
            early = [b for b in self.budgets if b < first]
            if early:
                warnings.warn(
                    f"{method} first updates its network after {first} interactions: at the "
                    f"budgets {early} it is scored untrained",
                    stacklevel=3,
                )

    def params(self) -> dict:
        """The constructor's arguments (written to ``summary.json``)."""
        return dict(vars(self))

    @classmethod
    def quick(cls, **overrides) -> Comparison:
        """Tiny budgets for tests: two seeds, small SB3 buffers and rollouts."""
        small = {
            "budgets": QUICK_BUDGETS,
            "seeds": 2,
            "eval_starts": 20,
            "dqn_kwargs": {"learning_starts": 100, "buffer_size": 1_000, "train_freq": 8},
            "ppo_kwargs": {"n_steps": 32, "batch_size": 64, "n_epochs": 2},
            "sac_kwargs": {"learning_starts": 100, "buffer_size": 1_000, "batch_size": 32},
        }
        return cls(**{**small, **overrides})

    def sb3_kwargs(self, method: str) -> dict:
        """Constructor arguments of the SB3 baseline ``method`` ("dqn", "ppo" or "sac").

        DQN and PPO take rl-zoo3's hyperparameters for Atari's images (its ``dqn.yml`` and
        ``ppo.yml``), scaled where they assume 10 million steps: DQN starts learning after
        a tenth of the largest budget instead of 100,000 steps. SAC has no Atari setting;
        it gets SB3's defaults with a cheaper update schedule for the CPU.
        """
        largest = max(self.budgets)
        if method == "dqn":
            zoo = {
                "buffer_size": min(100_000, largest),
                "learning_rate": 1e-4,
                "batch_size": 32,
                "learning_starts": min(100_000, largest // 10),
                "target_update_interval": 1_000,
                "train_freq": 4,
                "gradient_steps": 1,
                "exploration_fraction": 0.1,
                "exploration_final_eps": 0.01,
            }
            return {**zoo, **self.dqn_kwargs}
        if method == "ppo":
            zoo = {
                "n_steps": 128,
                "n_epochs": 4,
                "batch_size": 256,
                "learning_rate": _linear(2.5e-4),
                "clip_range": _linear(0.1),
                "vf_coef": 0.5,
                "ent_coef": 0.01,
            }
            return {**zoo, **self.ppo_kwargs}
        if method == "sac":
            # SB3's default, a batch of 256 images every interaction, takes 137 ms a step on a
            # 2-core CPU (2.3 hours a seed at 60,000); a batch of 64 every 4 steps takes 12 ms.
            replay = {
                "buffer_size": min(50_000, largest),
                "learning_starts": min(1_000, largest // 10),
            }
            return {**replay, "batch_size": 64, "train_freq": 4, **self.sac_kwargs}
        raise ValueError(f"no SB3 baseline called {method!r}")


def _linear(start: float) -> Callable[[float], float]:
    """rl-zoo3's ``lin_<start>``: decays linearly to 0 over the run (SB3 passes the progress
    remaining, 1 -> 0)."""
    return lambda progress_remaining: progress_remaining * start
