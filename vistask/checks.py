"""Argument checks shared by the whole library: ``@checked`` refuses arguments of another type
than their annotations name, the ``check_*`` functions refuse values out of range, another
env than the one learned on, devices the machine lacks; each error names the argument, its
value and what would be accepted.

Example:
    >>> @checked
    ... def fit(points: torch.Tensor, n_particles: int = 100, sigma_t: float = 0.01): ...
    >>> check_at_least(1, n_particles=100)
    >>> check_positive(sigma_t=0.01)
"""

from __future__ import annotations

import collections.abc
import functools
import inspect
import json
import math
import numbers
import os
import sys
import typing
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


def check_auto_or_integer(low: int, **values: object) -> None:
    """Raise unless every value is ``"auto"`` or an integer >= ``low``: ``ValueError`` for
    another string or a smaller integer, ``TypeError`` for another type."""
    for name, value in values.items():
        if isinstance(value, str):
            if value != "auto":
                raise ValueError(f"{name} must be 'auto' or an integer >= {low}, got {value!r}")
        else:
            check_integers(**{name: value})
            check_at_least(low, **{name: value})


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


def _split_union(text: str) -> list[str]:
    """``"A[B | C] | None"`` -> ``["A[B | C]", "None"]``: the options of a union."""
    options, depth, start = [], 0, 0
    for i, char in enumerate(text):
        depth += {"[": 1, "]": -1}.get(char, 0)
        if char == "|" and depth == 0:
            options.append(text[start:i].strip())
            start = i + 1
    return [*options, text[start:].strip()]


def _class_test(option: str, namespace: dict) -> tuple[str, Callable[[object], bool]] | None:
    """(what it accepts, test) for an annotation naming a class (``SE3KDE``, ``gym.Env``,
    ``torch.Tensor``, ``Sequence[str]``, ``Callable[...]``); None for what cannot be tested:
    array-likes (``np.ndarray``), protocols, type variables, ``Any``, unknown names."""
    try:
        value = eval(option, namespace)
    except Exception:
        return None
    origin = typing.get_origin(value) or value
    if origin is collections.abc.Callable:
        return "a function", callable
    if (
        not inspect.isclass(origin)
        or origin in (typing.Any, np.ndarray)
        or getattr(origin, "_is_protocol", False)
    ):
        return None
    if origin in (collections.abc.Sequence, list, tuple):  # what a JSON list or .values() gives
        return (
            "a list",
            lambda v: (
                isinstance(v, collections.abc.Collection | np.ndarray)
                and not isinstance(v, str | bytes | dict)
            ),
        )
    name = f"{origin.__module__.split('.')[0]}.{origin.__name__}"
    name = origin.__name__ if name.startswith(("vistask", "builtins")) else name
    # An env class also takes its wrappers (TimeLimit, ...): gym.make's envs.
    return (
        f"a {name}",
        lambda v: isinstance(v, origin) or isinstance(getattr(v, "unwrapped", None), origin),
    )


def _annotation_check(annotation: object, namespace: dict) -> Callable[[str, object], None] | None:
    """The check of a parameter by its annotation: scalars (``int``, ``float | None``,
    ``tuple[float, ...]``, ``str | Path``) and classes (``SE3KDE | None``); None when an
    option of the annotation cannot be tested."""
    text = annotation if isinstance(annotation, str) else inspect.formatannotation(annotation)
    text = text.replace("pathlib.", "").replace("os.PathLike", "Path")
    if text.startswith("tuple[") and text.endswith("]") and "|" not in text:
        items = [item.strip() for item in text[6:-1].split(",")]
        if not items or any(item not in (items[0], "...") for item in items):
            return None
        item_check = _annotation_check(items[0], namespace)
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
    options = _split_union(text)
    tests = [_SCALARS.get(option) or _class_test(option, namespace) for option in options]
    if not all(tests):
        return None
    accepted = " or ".join(what for what, _ in tests)
    finite_only = "float" in options

    def check(name: str, value: object) -> None:
        if not any(test(value) for _, test in tests):
            shown = repr(value) if len(repr(value)) < 80 else f"a {type(value).__name__}"
            # A Gymnasium vector env, or SB3's VecEnv.
            if hasattr(value, "single_observation_space") or hasattr(value, "num_envs"):
                shown += " (a vector env: pass one env, of which agents run n_envs copies)"
            raise TypeError(f"{name} must be {accepted}, got {shown}")
        if finite_only and isinstance(value, numbers.Real) and not math.isfinite(value):
            raise ValueError(f"{name} must be a finite number, got {value!r}")

    return check


def checked(target):
    """Decorator: refuse an argument whose type is not the one its annotation names, with an
    error naming the argument and its value, before the call runs: ``int`` refuses 1.7 and
    True, ``bool`` refuses ``"False"``, ``float`` refuses a string, a complex number, NaN and
    infinity, ``SE3KDE`` or ``torch.Tensor`` refuse anything else, ``Sequence[str]`` refuses a
    string. On a class it checks ``__init__`` and every public method the class defines.

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
    checks: dict | None = None  # on the first call: annotations may name later classes

    @functools.wraps(target)
    def checked_call(*args, **kwargs):
        nonlocal checks
        if checks is None:
            namespace = {**vars(typing), **target.__globals__}
            checks = {
                name: check
                for name, parameter in signature.parameters.items()
                if parameter.kind not in (parameter.VAR_POSITIONAL, parameter.VAR_KEYWORD)
                and (check := _annotation_check(parameter.annotation, namespace)) is not None
            }
        if checks:
            arguments = signature.bind(*args, **kwargs).arguments
            for name, check in checks.items():
                if name in arguments:
                    check(name, arguments[name])
        return target(*args, **kwargs)

    checked_call.__checked__ = True
    return checked_call


_HERE = os.path.dirname(os.path.realpath(__file__))
# vistask's folders; agents and envs may be links to folders beside it (an editable install).
_PACKAGE_DIRS = tuple(
    os.path.realpath(os.path.join(_HERE, sub)) + os.sep for sub in ("", "agents", "envs")
)


def warn(message: str, category: type[Warning] = UserWarning) -> None:
    """``warnings.warn`` pointing at the first caller outside vistask: the user's line."""
    level, frame = 2, sys._getframe(1)  # stacklevel 2: the frame that called warn
    while frame is not None and os.path.realpath(frame.f_code.co_filename).startswith(
        _PACKAGE_DIRS
    ):
        level, frame = level + 1, frame.f_back
    warnings.warn(message, category, stacklevel=level)


def env_identity(env) -> tuple[str, dict] | None:
    """An env's ``gym.make`` id and arguments as plain JSON values, its episode length among
    them (``max_episode_steps``); None for an env made without ``gym.make``."""
    spec = getattr(env, "spec", None)
    if spec is None:
        return None
    kwargs = {**spec.kwargs, "max_episode_steps": spec.max_episode_steps}
    return spec.id, json.loads(json.dumps(kwargs, default=_plain, sort_keys=True))


def _plain(value) -> str:
    """A ``gym.make`` argument that JSON does not hold, named the same in every process: a
    function or class by its import path, an object by its repr unless that holds its address
    (then by its type)."""
    if callable(value) and hasattr(value, "__qualname__"):
        return f"{getattr(value, '__module__', '')}.{value.__qualname__}"
    text = repr(value)
    if " at 0x" in text:
        return f"<{type(value).__module__}.{type(value).__qualname__}>"
    return text


def check_same_env(learned: tuple[str, dict] | None, env, learning: bool) -> None:
    """Compare ``env`` with the env an agent learned on (``learned``, its ``env_identity``):
    another id or other ``gym.make`` arguments raise ``ValueError`` when the agent would learn
    on it (its interactions would mix the two) and warn when it would only act on it."""
    now = env_identity(env)
    if learned is None or now is None:
        return
    if "max_episode_steps" not in learned[1]:  # a file saved before the episode length was
        now = (now[0], {k: v for k, v in now[1].items() if k != "max_episode_steps"})
    if tuple(learned) == now:
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


MAX_CANVAS_BYTES = 2**31  # an env's pre-drawn image: beyond 2 GiB, a unit or size mistake


def check_canvas(height: int, width: int, settings: str) -> None:
    """Raise ``ValueError`` when an RGB canvas of ``height`` x ``width`` pixels, which the
    ``settings`` named decide, would take more than ``MAX_CANVAS_BYTES``."""
    size = 3 * height * width
    if size > MAX_CANVAS_BYTES:
        raise ValueError(
            f"{settings} make a {height} x {width} pixel canvas of {size / 2**30:.3g} GiB "
            f"(at most {MAX_CANVAS_BYTES / 2**30:.0f} GiB)"
        )


def check_options(options: dict | None, known: tuple[str, ...]) -> dict:
    """``reset``'s options (``{}`` for None); ``ValueError`` for a key the env does not know."""
    options = {} if options is None else options
    if not isinstance(options, dict):
        raise TypeError(f"options must be a dict, got {options!r}")
    unknown = sorted(set(options) - set(known))
    if unknown:
        raise ValueError(f"options: unknown keys {unknown} (this env knows {list(known)})")
    return options
