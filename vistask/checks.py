"""Argument checks shared by every learner: each error names the argument, its value and what
would be accepted.

Example:
    >>> check_at_least(1, n_particles=n_particles, n_modes=n_modes)
    >>> check_positive(sigma_t=sigma_t, sigma_r=sigma_r)
"""

from __future__ import annotations

import functools
import inspect
import json
import math
import numbers
import os
import sys
import warnings
from collections.abc import Callable, Sequence

import numpy as np
import torch


def check_at_least(low: float, **values: float) -> None:
    """Raise ``ValueError`` unless every value is >= ``low`` (NaN is refused too)."""
    for name, value in values.items():
        if not value >= low:
            raise ValueError(f"{name} must be >= {low}, got {value!r}")


def check_positive(**values: float) -> None:
    """Raise ``ValueError`` unless every value is > 0 (NaN is refused too)."""
    for name, value in values.items():
        if not value > 0:
            raise ValueError(f"{name} must be positive, got {value!r}")


def check_integers(**values: object) -> None:
    """Raise ``TypeError`` unless every value is an integer (bool is not)."""
    for name, value in values.items():
        if not isinstance(value, numbers.Integral) or isinstance(value, bool):
            raise TypeError(f"{name} must be an integer, got {value!r}")


def check_bools(**values: object) -> None:
    """Raise ``TypeError`` unless every value is a bool (NumPy's too): a string such as
    ``"False"`` would otherwise switch an option on."""
    for name, value in values.items():
        if not isinstance(value, bool | np.bool_):
            raise TypeError(f"{name} must be True or False, got {value!r}")


def check_discount(gamma: float) -> None:
    """Raise ``ValueError`` unless ``gamma`` is a discount in [0, 1) (NaN is refused too)."""
    if not 0 <= gamma < 1:
        raise ValueError(f"gamma must be in [0, 1), got {gamma!r}")


_SCALARS = {
    "int": ("an integer", lambda v: isinstance(v, numbers.Integral) and not isinstance(v, bool)),
    "float": ("a number", lambda v: isinstance(v, numbers.Real) and not isinstance(v, bool)),
    "bool": ("True or False", lambda v: isinstance(v, bool | np.bool_)),
    "str": ("a string", lambda v: isinstance(v, str | os.PathLike)),  # paths are often str
    "Path": ("a path", lambda v: isinstance(v, os.PathLike)),
    "None": ("None", lambda v: v is None),
}


def _scalar_check(annotation: object) -> Callable[[str, object], None] | None:
    """The check of a parameter annotated with scalars (``int``, ``float | None``,
    ``tuple[float, ...]``, ``str | Path``); None for any other annotation."""
    text = annotation if isinstance(annotation, str) else inspect.formatannotation(annotation)
    text = text.replace("pathlib.", "").replace("os.", "")
    if text.startswith("tuple[") and text.endswith("]") and "|" not in text:
        items = [item.strip() for item in text[6:-1].split(",")]
        if not items or any(item not in (items[0], "...") for item in items):
            return None
        item_check = _scalar_check(items[0])
        if item_check is None:
            return None
        length = None if "..." in items else len(items)

        def check_tuple(name: str, value: object) -> None:
            if isinstance(value, str | bytes) or not isinstance(value, Sequence):
                raise TypeError(f"{name} must be a tuple of {items[0]}, got {value!r}")
            if length is not None and len(value) != length:
                raise ValueError(f"{name} must hold {length} values, got {value!r}")
            for i, item in enumerate(value):
                item_check(f"{name}[{i}]", item)

        return check_tuple
    options = [option.strip() for option in text.split("|")]
    if not all(option in _SCALARS for option in options):
        return None
    accepted = " or ".join(_SCALARS[option][0] for option in options)
    tests = [_SCALARS[option][1] for option in options]
    finite_only = "float" in options

    def check(name: str, value: object) -> None:
        if not any(test(value) for test in tests):
            raise TypeError(f"{name} must be {accepted}, got {value!r}")
        if finite_only and isinstance(value, numbers.Real) and not math.isfinite(value):
            raise ValueError(f"{name} must be a finite number, got {value!r}")

    return check


def checked(target):
    """Decorator: refuse an argument whose type is not the scalar its annotation names
    (``int`` refuses 1.7 and True, ``bool`` refuses ``"False"``, ``float`` refuses a string,
    a complex number, NaN and infinity), with an error naming the argument and its value,
    before the call runs. On a class it checks ``__init__`` and every public method the class
    defines.

    Example:
        >>> @checked
        ... def draw(n: int, scale: float = 1.0, verbose: bool = False): ...
        >>> draw(1.7)
        Traceback (most recent call last):
        TypeError: n must be an integer, got 1.7
    """
    if inspect.isclass(target):
        for name, member in list(vars(target).items()):
            if name != "__init__" and name.startswith("_"):
                continue
            if isinstance(member, staticmethod | classmethod):
                setattr(target, name, type(member)(checked(member.__func__)))
            elif inspect.isfunction(member):
                setattr(target, name, checked(member))
        target.__checked__ = True
        return target
    signature = inspect.signature(target)
    checks = {
        name: check
        for name, parameter in signature.parameters.items()
        if parameter.kind not in (parameter.VAR_POSITIONAL, parameter.VAR_KEYWORD)
        and (check := _scalar_check(parameter.annotation)) is not None
    }
    if not checks:
        target.__checked__ = True
        return target

    @functools.wraps(target)
    def checked_call(*args, **kwargs):
        arguments = signature.bind(*args, **kwargs).arguments
        for name, check in checks.items():
            if name in arguments:
                check(name, arguments[name])
        return target(*args, **kwargs)

    checked_call.__checked__ = True
    return checked_call


_PACKAGE = (os.path.dirname(os.path.dirname(os.path.realpath(__file__))), os.sep)


def warn(message: str, category: type[Warning] = UserWarning) -> None:
    """``warnings.warn`` pointing at the first caller outside vistask: the user's line."""
    level, frame = 1, sys._getframe(1)
    while (
        frame is not None
        and os.path.realpath(frame.f_code.co_filename).startswith(_PACKAGE[0] + _PACKAGE[1])
        and "site-packages" not in frame.f_code.co_filename
    ):
        level, frame = level + 1, frame.f_back
    warnings.warn(message, category, stacklevel=level)


def env_identity(env) -> tuple[str, dict] | None:
    """An env's ``gym.make`` id and arguments as plain JSON values; None for an env made
    without ``gym.make``."""
    spec = getattr(env, "spec", None)
    if spec is None:
        return None
    return spec.id, json.loads(json.dumps(spec.kwargs, default=repr, sort_keys=True))


def check_same_env(learned: tuple[str, dict] | None, env, learning: bool) -> None:
    """Compare ``env`` with the env an agent learned on (``learned``, its ``env_identity``):
    another id or other ``gym.make`` arguments raise ``ValueError`` when the agent would learn
    on it (its interactions would mix the two) and warn when it would only act on it."""
    now = env_identity(env)
    if learned is None or now is None or tuple(learned) == now:
        return
    message = (
        f"env: the agent learned on {learned[0]} with {learned[1]}; this env is {now[0]} with "
        f"{now[1]}"
    )
    if learning:
        raise ValueError(f"{message}. Learning on would mix their interactions: start a new agent")
    warn(f"{message}: acting on another env than it learned on")


def check_device(device) -> torch.device:
    """``device`` as a ``torch.device`` this machine has: a ``ValueError`` naming it for a
    name torch does not know (``"gpu"``) or a CUDA device that is not here."""
    try:
        device = torch.device(device)
    except (RuntimeError, TypeError) as error:
        raise ValueError(
            f"device must name a torch device such as 'cpu' or 'cuda', got {device!r}"
        ) from error
    if device.type == "cuda":
        count = torch.cuda.device_count()
        if (device.index or 0) >= count:
            raise ValueError(
                f"device {str(device)!r} is not available: this machine has {count} CUDA device(s)"
            )
    elif device.type not in ("cpu", "meta"):
        raise ValueError(f"device must be 'cpu' or a CUDA device, got {str(device)!r}")
    return device
