"""RLVC's settings per env id, as rl-zoo3 keeps hyperparameters per env: the table in
``hyperparams/rlvc.yml``, overridden by ``key=value`` strings from the command line.

Example:
    >>> params = hyperparams_for("vistask/VisualMountainCar-v0", parse_overrides(["seed=1"]))
    ValueError: ... unknown hyperparameter 'seed' ...
    >>> params = hyperparams_for("vistask/VisualMountainCar-v0", {"compaction": False})
    >>> agent = RLVCAgent(env, **agent_kwargs(params))
"""

from __future__ import annotations

import dataclasses
import inspect
from collections.abc import Iterable
from pathlib import Path

import yaml

from vistask.agents import Compaction, RLVCAgent

TABLE = Path(__file__).with_name("hyperparams") / "rlvc.yml"
# Arguments of RLVCAgent that are not settings of a configuration: the scripts give them.
NOT_HYPERPARAMS = ("self", "env", "tensorboard_log", "seed")


def known(agent_class: type = RLVCAgent) -> list[str]:
    """The hyperparameters: the agent class's arguments but the env, its log folder and
    seed."""
    names = inspect.signature(agent_class.__init__).parameters
    return [name for name in names if name not in NOT_HYPERPARAMS]


def table() -> dict[str, dict]:
    """The whole table: env id -> its hyperparameters."""
    return yaml.safe_load(TABLE.read_text()) or {}


def hyperparams_for(
    env_id: str, overrides: dict | None = None, agent_class: type = RLVCAgent
) -> dict:
    """The table's entry for ``env_id`` (empty if it has none), with ``overrides`` on top; a
    mapping over a mapping (``compaction``) overrides only its own keys. ``agent_class``:
    ``RLVCAgent``, or ``RLJCAgent`` for an env of continuous actions.

    Raises:
        ValueError: a key that is not one of ``known(agent_class)``, or a ``compaction``
            mapping with a key that ``Compaction`` does not take.
    """
    params = dict(table().get(env_id, {}))
    for key, value in (overrides or {}).items():
        both = isinstance(value, dict) and isinstance(params.get(key), dict)
        params[key] = {**params[key], **value} if both else value
    unknown = sorted(set(params) - set(known(agent_class)))
    if unknown:
        raise ValueError(
            f"unknown hyperparameter {', '.join(map(repr, unknown))}: "
            f"{agent_class.__name__} takes {', '.join(known(agent_class))}"
        )
    compaction = params.get("compaction")
    fields = [field.name for field in dataclasses.fields(Compaction)]
    if isinstance(compaction, dict) and not set(compaction) <= set(fields):
        raise ValueError(
            f"compaction takes true, false or a mapping of {', '.join(fields)}, got {compaction}"
        )
    return params


def parse_overrides(items: Iterable[str]) -> dict:
    """``["compounds=true", "compaction={tolerance: 0.01}"]`` -> a dict, each value read as
    YAML (numbers, true/false, null, mappings)."""
    overrides = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ValueError(f"a hyperparameter is key=value, got {item!r}")
        try:
            overrides[key.strip()] = yaml.safe_load(value)
        except yaml.YAMLError as error:
            raise ValueError(f"hyperparameter {key!r}: {value!r} is not a YAML value") from error
    return overrides


def agent_kwargs(params: dict) -> dict:
    """``RLVCAgent`` keyword arguments of ``params`` (a ``compaction`` mapping becomes a
    ``Compaction``)."""
    kwargs = dict(params)
    if isinstance(kwargs.get("compaction"), dict):
        kwargs["compaction"] = Compaction(**kwargs["compaction"])
    return kwargs
