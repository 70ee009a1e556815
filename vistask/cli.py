"""Argument types that the scripts share: each rejects a bad value with argparse's own error,
before any work starts."""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import gymnasium as gym

from vistask.checks import check_device
from vistask.parallel import RunsFailed, unreachable
from vistask.runs import held_run_folder, holding_run_folders


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


_received: list[str] = []  # the signals that interrupt_on_sigterm turned into interrupts


def interrupt_on_sigterm() -> None:
    """Turn SIGTERM (a scheduler or ``kill`` stopping the run) into KeyboardInterrupt, so that
    a stopped run closes its simulators and workers as Ctrl-C does; its checkpoints are
    already on disk."""

    def interrupt(signum, frame):
        _received.append(signal.Signals(signum).name)
        raise KeyboardInterrupt(_received[-1])

    signal.signal(signal.SIGTERM, interrupt)


def stopped_run_settings(
    parser: argparse.ArgumentParser, folder: Path, name: str, runs: tuple[str, ...] = ()
) -> dict:
    """The settings a stopped run wrote to ``folder/name``, for ``--resume folder``; argparse's
    own error when the folder holds no stopped run, or a run of another kind than ``runs``
    (the names its ``run.json`` may give; default: the script's own name)."""
    path = Path(folder) / name
    record = Path(folder) / "run.json"
    runs = runs or (Path(parser.prog).stem,)
    if record.is_file():
        try:
            made_by = json.loads(record.read_text()).get("script")
        except (json.JSONDecodeError, AttributeError):
            made_by = None
        if made_by is not None and made_by not in runs:
            parser.error(f"argument --resume: {folder} holds a run of {made_by!r}, not {runs}")
    if not path.is_file():
        parser.error(f"argument --resume: {folder} holds no stopped run (no {name})")
    try:
        settings = json.loads(path.read_text())
    except json.JSONDecodeError as error:
        parser.error(f"argument --resume: {path} is not valid JSON ({error})")
    if not isinstance(settings, dict):
        parser.error(f"argument --resume: {path} holds no settings (not a JSON object)")
    return settings


def torch_device(text: str) -> str:
    """A torch device this machine has (``cpu``, ``cuda``, ``cuda:1``)."""
    try:
        check_device(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None
    return text


def ray_address(text: str) -> str:
    """A Ray cluster to reach: ``local``, ``auto``, or ``[ray://]host:port`` that answers."""
    if text in ("local", "auto"):
        return text
    host, _, port = text.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        raise argparse.ArgumentTypeError(
            f"must be 'local', 'auto' or [ray://]host:port, got {text}"
        )
    why = unreachable(text)
    if why is not None:
        raise argparse.ArgumentTypeError(why)
    return text


def add_address(parser: argparse.ArgumentParser, runs: str = "the runs") -> None:
    """``--address``: a Ray cluster for ``runs``; the same option in every script."""
    parser.add_argument(
        "--address",
        type=ray_address,
        default=None,
        help=f"a Ray cluster for {runs} ([ray://]host:port, or 'local' for a Ray on this "
        "machine; default: RAY_ADDRESS, else no Ray)",
    )


@contextmanager
def restored(signum: int, handler) -> Iterator[None]:
    """Set ``handler`` for signal ``signum`` again when the block ends."""
    try:
        yield
    finally:
        signal.signal(signum, handler)


def run_main(main: Callable[[], object], go_on: str = "") -> None:
    """Run a script's ``main``; an input refused on the way (``ValueError``, ``TypeError``,
    ``FileNotFoundError``, a gymnasium error, a module named in an env id that does not
    import: ``ModuleNotFoundError``) or a run that would not fit in memory
    (``MemoryError``) ends it with one line, as argparse's errors do (exit status 2); runs
    that failed (``RunsFailed``) end it with their errors' last lines, and a file that could
    not be written (``OSError``, such as a full disk) with its path (exit status 1).
    ``VISTASK_TRACEBACK=1`` shows the traceback instead.

    The script holds the run folders it makes (``runs.holding_run_folders``). A stop (Ctrl-C,
    or SIGTERM, which ``interrupt_on_sigterm`` turns into one meanwhile) ends it with a line
    naming its folder and how to go on (exit status 130).

    Args:
        go_on: how to go on after a stop, ``{out}`` standing for the run folder (such as
            ``"python scripts/train_rlvc.py --resume {out}"``); empty: the script does not
            resume.
    """
    refused = (ValueError, TypeError, FileNotFoundError, ModuleNotFoundError, MemoryError)
    script = Path(sys.argv[0]).name
    before = signal.getsignal(signal.SIGTERM)
    interrupt_on_sigterm()
    with holding_run_folders(), restored(signal.SIGTERM, before):
        try:
            main()
        except (*refused, gym.error.Error, RunsFailed, OSError) as error:
            if os.environ.get("VISTASK_TRACEBACK"):
                raise
            print(f"{script}: error: {error}", file=sys.stderr)
            print("(VISTASK_TRACEBACK=1 shows where it was raised)", file=sys.stderr)
            sys.exit(2 if isinstance(error, (*refused, gym.error.Error)) else 1)
        except KeyboardInterrupt as stop:
            if os.environ.get("VISTASK_TRACEBACK"):
                raise
            # The signal's name: a library between (Ray) may raise its own bare interrupt.
            why = _received[-1] if _received else str(stop) or "Ctrl-C"
            line = f"\n{script}: stopped by {why}"
            out = held_run_folder()
            if out is not None:
                line += f"; {out} keeps what it finished"
                line += f": go on with {go_on.format(out=out)}" if go_on else ""
            print(line, file=sys.stderr)
            sys.exit(130)


def check_resume_alone(
    parser: argparse.ArgumentParser, args: argparse.Namespace, keep: tuple[str, ...] = ()
) -> None:
    """With ``--resume``, argparse's error for any flag given that the stopped run's settings
    fix (all but ``--resume`` and the flags named in ``keep``, by their dest)."""
    typed = {token.split("=")[0] for token in sys.argv[1:] if token.startswith("--")}
    given = [
        action.option_strings[0]
        for action in parser._actions
        if action.option_strings
        and action.dest not in ("help", "resume", *keep)
        and (
            getattr(args, action.dest) != action.default
            or any(t in action.option_strings for t in typed)  # given, if at its default
        )
    ]
    if given:
        parser.error(
            f"argument --resume: a resumed run goes on with the settings it started with; "
            f"drop {' '.join(given)}"
        )
