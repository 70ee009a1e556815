"""Argument checks shared by every learner: each error names the argument, its value and what
would be accepted.

Example:
    >>> check_at_least(1, n_particles=n_particles, n_modes=n_modes)
    >>> check_positive(sigma_t=sigma_t, sigma_r=sigma_r)
"""

from __future__ import annotations

import numbers

import numpy as np


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
