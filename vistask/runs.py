"""Run directories, TensorBoard writers and JSON summaries shared by every script."""

from __future__ import annotations

import fcntl
import json
import math
import os
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

import numpy as np

from vistask.saving import cannot_write

# The run folders this process holds (``holding_run_folders``): the folder as given and its open
# lock file, by the folder's resolved path.
_held: dict[Path, tuple[Path, IO[str]]] | None = None


@contextmanager
def holding_run_folders() -> Iterator[None]:
    """Inside the block, ``run_dir`` holds each folder it gives: another process asking
    ``run_dir`` for it is refused until the block ends. Scripts run inside one
    (``cli.run_main``), so that two commands never write one run; the lock goes with the
    process, ``kill -9`` included."""
    global _held
    if _held is not None:  # already holding
        yield
        return
    _held = {}
    try:
        yield
    finally:
        for _, lock in _held.values():
            lock.close()
        _held = None


def held_run_folder() -> Path | None:
    """The first run folder this process holds (None: none, or not holding)."""
    return next(iter(_held.values()))[0] if _held else None


def _hold(path: Path) -> None:
    if _held is None or path.resolve() in _held:
        return
    try:
        lock = open(path / ".lock", "a+")  # noqa: SIM115 (open while the process runs)
    except OSError as error:
        raise ValueError(f"out: cannot write in the run folder {path}: {error.strerror}") from None
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        lock.seek(0)
        owner = lock.read().strip() or "unknown"
        lock.close()
        raise ValueError(
            f"out: {path} is in use by another run (process {owner}): wait for it to end, "
            "or pick another output folder"
        ) from None
    except OSError:  # a file system without locks (some network ones): run unguarded
        lock.close()
        return
    lock.truncate(0)
    lock.write(f"{os.getpid()}\n")
    lock.flush()
    _held[path.resolve()] = path, lock


def run_dir(script: str, out: str | Path | None = None) -> Path:
    """``out`` if given, else ``runs/<script>-<YYYYmmdd-HHMMSS>/``; created.

    The folder's ``run.json`` records the script that made it and the command line of every
    call on it; a folder that another script made is refused, so that no run overwrites
    another's results. Inside ``holding_run_folders`` (as in the scripts), a folder another
    process holds is refused too.
    """
    path = Path(out) if out else Path("runs") / f"{script}-{time.strftime('%Y%m%d-%H%M%S')}"
    if path.exists() and not path.is_dir():
        raise ValueError(f"out: {path} is a file, not a folder for the run")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as error:  # read-only, not permitted, a file on the way
        raise ValueError(f"out: cannot make the run folder {path}: {error.strerror}") from None
    _hold(path)
    record = path / "run.json"
    run = read_json(record) if record.exists() else {"script": script, "commands": []}
    if run.get("script") != script:
        raise ValueError(
            f"{path} holds a run of {run.get('script')!r}, not of {script!r}: pick another "
            "output folder"
        )
    run["commands"].append([Path(sys.argv[0]).name, *sys.argv[1:]])
    write_json(record, run)
    return path


def read_json(path: str | Path) -> Any:
    """The JSON value in ``path``; a file that is not JSON gives an error naming it."""
    try:
        return json.loads(Path(path).read_text())
    except json.JSONDecodeError as error:
        raise ValueError(f"{path} is not valid JSON ({error}): remove or repair it") from None


def tensorboard(path: str | Path):
    """A TensorBoard ``SummaryWriter`` logging under ``path``."""
    from torch.utils.tensorboard import SummaryWriter  # imports tensorboard: slow, so lazy

    return SummaryWriter(log_dir=str(path))


def _plain(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return _plain(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None  # JSON has no inf or nan
    if isinstance(value, np.ndarray):
        return value.tolist()
    return value


def write_json(path: str | Path, value: Any) -> None:
    """Write ``value`` as indented JSON (NumPy values converted) in one step: a run killed
    meanwhile leaves the old file or the new one, never a part."""
    path = Path(path)
    partial = path.with_name(path.name + ".partial")
    text = json.dumps(_plain(value), indent=2, allow_nan=False) + "\n"
    try:
        partial.write_text(text)
    except OSError as error:  # a full disk: no part left behind
        partial.unlink(missing_ok=True)
        raise OSError(cannot_write(path, error)) from error
    os.replace(partial, path)


def write_summary(path: str | Path, summary: dict) -> Path:
    """Write ``summary`` as indented JSON (NumPy scalars and arrays converted)."""
    path = Path(path)
    if path.is_dir():
        path = path / "summary.json"
    write_json(path, summary)
    return path


def append_record(path: str | Path, record: dict) -> None:
    """Append ``record`` to the JSON-lines file ``path`` as one line (NumPy values
    converted), so that a stopped run keeps every record finished before it stopped."""
    with open(path, "a") as f:
        f.write(json.dumps(_plain(record), allow_nan=False) + "\n")


def read_records(path: str | Path) -> list[dict]:
    """The records that ``append_record`` wrote to ``path`` (none if there is no file)."""
    path = Path(path)
    if not path.exists():
        return []
    text = path.read_text()
    if not text.endswith("\n"):  # a line cut short by a kill: its record is made again
        text = text[: text.rfind("\n") + 1]
    records = []
    for number, line in enumerate(text.splitlines(), 1):
        try:
            records.extend([json.loads(line)] if line else [])
        except json.JSONDecodeError:
            raise ValueError(
                f"{path}, line {number}, is not valid JSON: remove or repair it"
            ) from None
    return records


def print_table(rows: dict[str, Any], title: str = "") -> None:
    """Print ``name value`` rows aligned, numbers with 4 significant digits."""
    if title:
        print(title)
    width = max(len(k) for k in rows)
    for key, value in rows.items():
        text = f"{value:.4g}" if isinstance(value, float) else str(value)
        print(f"{key:<{width}}  {text}")


def _short(value: Any, width: int = 60) -> str:
    """``value`` as compact JSON, cut to ``width`` characters."""
    text = json.dumps(value, separators=(",", ":"))
    return text if len(text) <= width else text[: width - 3] + "..."


def check_same_settings(path: str | Path, settings: dict, free: tuple[str, ...] = ()) -> None:
    """Write ``settings`` to ``path`` (JSON), or, if a stopped run left it there, check that
    they are the same: resuming must never mix two configurations in one folder.

    Args:
        free: keys that may change from the stopped run to its resumption (such as the list
            of objects of a run whose objects do not depend on one another); the file then
            holds the new values.
    """
    path = Path(path)
    settings = json.loads(json.dumps(_plain(settings)))
    if not path.exists():
        write_json(path, settings)
        return
    before = read_json(path)
    if not isinstance(before, dict):
        raise ValueError(f"{path} holds no settings (not a JSON object): remove or repair it")
    changed = sorted(
        k
        for k in settings.keys() | before.keys()
        if before.get(k) != settings.get(k) and k not in free
    )
    if changed:
        differences = [
            f"{k} {_short(before.get(k))} there, {_short(settings.get(k))} now" for k in changed
        ]
        raise ValueError(
            f"{path.parent} holds a run with other settings ({'; '.join(differences)}); "
            "resume it with the same settings or pick another output folder"
        )
    if before != settings:
        write_json(path, settings)
