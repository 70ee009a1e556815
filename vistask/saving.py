"""Files of learned models: one format for every learner, written atomically, checked on load.

A file is ``torch.save`` of ``{"kind": ..., "version": ..., "state": ...}`` holding tensors and
plain Python values only, so that ``torch.load(weights_only=True)`` reads it safely.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import torch

VERSION = 1


def save_state(path: str | Path, kind: str, state: dict) -> Path:
    """Write ``state`` of a ``kind`` of model (e.g. ``"RLVCAgent"``) to ``path``.

    The file is written next to its destination and renamed into place, so that a crash
    mid-write never leaves a corrupt file where a good one was; a write that fails (a full
    disk) removes its part and raises ``OSError`` naming the path and the space left.
    """
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"path: {path} is a folder; name a file in it to save to")
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(f".{path.name}.partial")
    try:
        torch.save({"kind": kind, "version": VERSION, "state": state}, partial)
    except Exception as error:  # torch reports a full disk as a RuntimeError
        partial.unlink(missing_ok=True)
        raise OSError(cannot_write(path, error)) from error
    os.replace(partial, path)
    return path


def cannot_write(path: Path, error: Exception) -> str:
    """Why ``path`` was not written: ``error`` and the space left on its disk."""
    free = shutil.disk_usage(path.parent).free / 2**20
    kept = "the file there before is kept" if path.exists() else "nothing was written"
    return f"cannot write {path} ({error}; {free:.0f} MB free on its disk): {kept}"


def load_state(path: str | Path, kind: str) -> dict:
    """The state saved by ``save_state(path, kind, state)``; a clear ``ValueError`` for a file
    that is truncated, not a saved model, another kind of model or another format version."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no saved {kind} at {path}")
    try:
        saved = torch.load(path, weights_only=True, map_location="cpu")
    except Exception as error:  # torch raises several types for damaged files
        raise ValueError(
            f"{path} cannot be read as a saved {kind} (truncated or not a vistask file): {error}"
        ) from None
    if not isinstance(saved, dict) or "kind" not in saved or "state" not in saved:
        raise ValueError(f"{path} is not a vistask model file (expected a saved {kind})")
    if saved["kind"] != kind:
        raise ValueError(f"{path} holds a {saved['kind']}, not a {kind}: load it with its class")
    if saved.get("version") != VERSION:
        raise ValueError(
            f"{path} has format version {saved.get('version')}; this vistask reads {VERSION}"
        )
    return saved["state"]
