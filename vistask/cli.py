"""Argument types that the scripts share: each rejects a bad value with argparse's own error,
before any work starts."""

from __future__ import annotations

import argparse
import json
import math
import signal
from collections.abc import Callable
from pathlib import Path


def _checked(text: str, convert: Callable[[str], float], ok: Callable, accepted: str):
    value = convert(text)
    if not ok(value):
        raise argparse.ArgumentTypeError(f"must be {accepted}, got {text}")
    return value


def positive_int(text: str) -> int:
    """An integer >= 1."""
    return _checked(text, int, lambda v: v >= 1, "a positive integer")


def non_negative_int(text: str) -> int:
    """An integer >= 0."""
    return _checked(text, int, lambda v: v >= 0, "an integer >= 0")


def non_negative_float(text: str) -> float:
    """A finite float >= 0."""
    return _checked(text, float, lambda v: 0 <= v < math.inf, "a finite number >= 0")


def unit_fraction(text: str) -> float:
    """A float in [0, 1)."""
    return _checked(text, float, lambda v: 0 <= v < 1, "in [0, 1)")


def probability(text: str) -> float:
    """A float in [0, 1]."""
    return _checked(text, float, lambda v: 0 <= v <= 1, "in [0, 1]")


def json_object(text: str) -> dict:
    """A JSON object (``--env-kwargs '{"layout_seed": 7}'``)."""
    try:
        value = json.loads(text)
    except json.JSONDecodeError as error:
        raise argparse.ArgumentTypeError(f"must be a JSON object, got {text} ({error})") from None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError(
            f"must be a JSON object such as '{{\"a\": 1}}', got {text}"
        )
    return value


def interrupt_on_sigterm() -> None:
    """Turn SIGTERM (a scheduler or ``kill`` stopping the run) into KeyboardInterrupt, so that
    a stopped run closes its simulators and workers as Ctrl-C does; its checkpoints are
    already on disk."""

    def interrupt(signum, frame):
        raise KeyboardInterrupt(f"signal {signum}")

    signal.signal(signal.SIGTERM, interrupt)


def stopped_run_settings(parser: argparse.ArgumentParser, folder: Path, name: str) -> dict:
    """The settings a stopped run wrote to ``folder/name``, for ``--resume folder``; argparse's
    own error when the folder holds no stopped run."""
    path = Path(folder) / name
    if not path.is_file():
        parser.error(f"argument --resume: {folder} holds no stopped run (no {name})")
    try:
        settings = json.loads(path.read_text())
    except json.JSONDecodeError as error:
        parser.error(f"argument --resume: {path} is not valid JSON ({error})")
    if not isinstance(settings, dict):
        parser.error(f"argument --resume: {path} holds no settings (not a JSON object)")
    return settings
