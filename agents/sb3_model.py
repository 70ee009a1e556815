"""What Stable-Baselines3's callbacks and logger expect of a model, shared by the agents."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
from stable_baselines3.common.callbacks import BaseCallback, CallbackList, ConvertCallback
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.utils import configure_logger
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv

from vistask.checks import checked


class StageLogger(Logger):
    """SB3's logger with one axis: once an agent sets ``stage``, every dump, an SB3
    callback's own (``EvalCallback`` dumps at its interaction count) included, is written at
    that stage."""

    stage: int | None = None

    def dump(self, step: int = 0) -> None:
        """Write the pending records at ``stage``, or at ``step`` while it is None."""
        super().dump(step if self.stage is None else self.stage)


@checked
class SB3Model:
    """Base of the agents: ``get_env``, ``get_vec_normalize_env`` and ``logger`` as SB3
    callbacks read them, and ``_start_learning``, which sets up the TensorBoard run and the
    callbacks of one ``learn`` call as SB3's ``BaseAlgorithm._setup_learn`` does."""

    env: gym.Env | None
    num_timesteps: int
    tensorboard_log: str | Path | None = None
    _logger: Logger | None = None
    _vec_env: VecEnv | None = None

    def get_env(self) -> VecEnv | None:
        """The env as a one-copy SB3 ``VecEnv`` (what SB3 callbacks read)."""
        if self._vec_env is None and self.env is not None:
            self._vec_env = DummyVecEnv([lambda: self.env])
        return self._vec_env

    def get_vec_normalize_env(self) -> None:
        """None: the agents read raw observations (what SB3 callbacks ask for)."""
        return None  # the agents read raw observations

    @property
    def _saved_tensorboard_log(self) -> str | None:
        """``tensorboard_log`` as a saved agent holds it (a string; None: no logging)."""
        return None if self.tensorboard_log is None else str(self.tensorboard_log)

    @property
    def logger(self) -> StageLogger:
        """SB3's logger of the current ``learn`` call (silent without ``tensorboard_log``)."""
        if self._logger is None:
            # SB3's configure_logger(0, None) would make an empty /tmp/SB3-<time> folder
            self._logger = StageLogger(folder=None, output_formats=[])
        return self._logger

    def _start_learning(
        self, callback: Any, tb_log_name: str, reset_num_timesteps: bool
    ) -> BaseCallback:
        """Reset the count if asked, open the TensorBoard run, wrap and start the callbacks
        (an SB3 ``BaseCallback``, a function(locals, globals) -> bool, or a list of them)."""
        if self.env is None:
            raise ValueError(
                f"this {type(self).__name__} has no env: pass one to load(path, env=env)"
            )
        if reset_num_timesteps:
            self.num_timesteps = 0
        self._logger = None  # no TensorBoard folder: the silent logger of ``logger``
        if self.tensorboard_log is not None:
            sb3 = configure_logger(0, self.tensorboard_log, tb_log_name, reset_num_timesteps)
            self._logger = StageLogger(sb3.dir, sb3.output_formats)

        def convert(c: Any) -> BaseCallback:
            if not (isinstance(c, BaseCallback) or callable(c)):
                raise TypeError(
                    f"callback must be an SB3 BaseCallback, a function(locals, globals) or a "
                    f"list of them, got {c!r}"
                )
            return c if isinstance(c, BaseCallback) else ConvertCallback(c)

        if callback is None or isinstance(callback, list):
            callback = CallbackList([convert(c) for c in callback or []])
        callback = convert(callback)
        callback.init_callback(self)
        callback.on_training_start(locals(), globals())
        return callback

    def _end_learning(self, callback: BaseCallback) -> None:
        callback.on_training_end()
        self.logger.close()
        self._logger = None
