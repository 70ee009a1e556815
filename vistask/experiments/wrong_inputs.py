"""A sweep of wrong inputs over the Python API and the scripts: each case is tried as a user
would and its answer counted as clear (refused, the message names what is wrong), unclear (an
error whose message names nothing of the input, or a traceback from a script) or silent
(accepted).

Example:
    >>> case = Case("ranges", "SE3KDE(sigma_t=0)", call=lambda: SE3KDE(points, sigma_t=0),
    ...             names=("sigma_t",))
    >>> answer(case).outcome
    'clear'
"""

from __future__ import annotations

import inspect
import json
import math
import os
import subprocess
import sys
import traceback
import warnings
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import gymnasium as gym

OUTCOMES = ("clear", "unclear", "silent")
ROOT = Path(__file__).resolve().parents[2]
# RuntimeError: a call out of order ("call reset() before step()"), when its message says so.
REFUSALS = (ValueError, TypeError, FileNotFoundError, RuntimeError, gym.error.Error)


@dataclass
class Case:
    """One wrong input.

    Args:
        kind: the kind of mistake (e.g. ``"types"``, ``"ranges"``, ``"scripts"``).
        what: the input as a user would write it.
        call: the API call to try (None for a script case).
        argv: a script case: the script's file name under ``scripts/`` and its arguments.
        names: what a clear answer names (the argument or flag), matched case-insensitively.
        setup: a script case: run before it in its working folder (writes files it reads).
        result: an input to be handled, not refused: ``call`` raises ``ArithmeticError`` when
            the result is wrong (silent), returns when it is right (clear).
    """

    kind: str
    what: str
    call: Callable[[], object] | None = None
    argv: Sequence[str] = ()
    names: Sequence[str] = ()
    setup: Callable[[Path], None] | None = None
    result: bool = False


# Values of the wrong type for a parameter annotated with each scalar type.
WRONG_TYPES = {
    "int": (1.7, "3", True),
    "float": ("0.5", 1j, math.nan),
    "bool": ("False", 1, None),
}


def type_cases(label: str, fn: Callable, **kwargs) -> Iterator[Case]:
    """A value of another type for every int, float and bool parameter of ``fn``, the others
    as ``kwargs`` give them."""
    target = fn.__init__ if inspect.isclass(fn) else fn
    for name, parameter in inspect.signature(inspect.unwrap(target)).parameters.items():
        annotation = parameter.annotation
        if not isinstance(annotation, str):
            annotation = inspect.formatannotation(annotation)
        optional = annotation.endswith(" | None")
        for value in WRONG_TYPES.get(annotation.removesuffix(" | None"), ()):
            if value is None and optional:
                continue

            def call(name=name, value=value):
                return fn(**{**kwargs, name: value})

            yield Case("types", f"{label}({name}={value!r})", call, names=(name,))


def case(kind: str, what: str, call: Callable[[], object], *names: str) -> Case:
    """An API case whose clear answer names ``names``."""
    return Case(kind, what, call, names=names)


@dataclass
class Answer:
    """How a case was answered: ``outcome`` in OUTCOMES and the message (first line)."""

    kind: str
    what: str
    outcome: str
    message: str = field(default="")


def _names_all(text: str, names: Sequence[str]) -> bool:
    """Whether ``text`` names each of ``names``; a flag ``--a-b`` is named as such or as the
    setting ``a_b`` it sets."""
    text = text.lower()
    return all(
        name.lower() in text or name.lower().removeprefix("--").replace("-", "_") in text
        for name in names
    )


def answer_call(case: Case) -> Answer:
    """Try an API case in this process."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            case.call()
    except Exception as error:
        message = f"{type(error).__name__}: {error}"
        origin = traceback.extract_tb(error.__traceback__)[-1].filename
        ours = "vistask" in origin or "gymnasium" in origin
        clear = isinstance(error, REFUSALS) and ours and _names_all(str(error), case.names)
        return Answer(case.kind, case.what, "clear" if clear else "unclear", message)
    if case.result:
        return Answer(case.kind, case.what, "clear", "handled")
    return Answer(case.kind, case.what, "silent", "accepted")


def answer_script(case: Case, folder: Path, timeout: float) -> Answer:
    """Run a script case in a fresh process in ``folder``; accepted if it is still working
    after ``timeout`` seconds."""
    folder.mkdir(parents=True, exist_ok=True)
    if case.setup is not None:
        case.setup(folder)
    command = [sys.executable, str(ROOT / "scripts" / case.argv[0]), *case.argv[1:]]
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    try:
        done = subprocess.run(
            command, cwd=folder, env=env, capture_output=True, text=True, timeout=timeout
        )
    except subprocess.TimeoutExpired:
        return Answer(case.kind, case.what, "silent", f"still working after {timeout:.0f} s")
    err = done.stderr.strip()
    last = err.splitlines()[-1] if err else ""
    if done.returncode == 0:
        return Answer(case.kind, case.what, "silent", "finished")
    clear = "Traceback" not in err and _names_all(err, case.names)
    return Answer(case.kind, case.what, "clear" if clear else "unclear", last)


def sweep(
    cases: Sequence[Case], folder: Path, workers: int = 2, timeout: float = 60.0
) -> list[Answer]:
    """Answer every case: API cases one after the other here, script cases ``workers`` at a
    time in their own processes, each in a folder of its own under ``folder``."""
    api = [answer_call(case) for case in cases if case.call is not None]
    scripts = [case for case in cases if case.call is None]
    with ThreadPoolExecutor(workers) as pool:
        ran = pool.map(
            lambda item: answer_script(item[1], folder / f"case{item[0]:03d}", timeout),
            enumerate(scripts),
        )
        return api + list(ran)


def summary(answers: Sequence[Answer]) -> dict:
    """Counts by outcome, overall and per kind, with the cases that were not clear."""
    kinds = sorted({a.kind for a in answers})
    per_kind = {k: Counter(a.outcome for a in answers if a.kind == k) for k in kinds}
    return {
        "cases": len(answers),
        "outcomes": {o: sum(a.outcome == o for a in answers) for o in OUTCOMES},
        "kinds": {k: {o: per_kind[k][o] for o in OUTCOMES} for k in kinds},
        "not_clear": [vars(a) for a in answers if a.outcome != "clear"],
    }


def table(result: dict) -> str:
    """The summary as a Markdown table, one row per kind and a total."""
    rows = ["| kind | cases | clear | unclear | silent |", "|---|---:|---:|---:|---:|"]
    for kind, counts in result["kinds"].items():
        rows.append(
            f"| {kind} | {sum(counts.values())} | "
            + " | ".join(str(counts[o]) for o in OUTCOMES)
            + " |"
        )
    total = result["outcomes"]
    rows.append(
        f"| all | {result['cases']} | " + " | ".join(str(total[o]) for o in OUTCOMES) + " |"
    )
    return "\n".join(rows)


def plot(result: dict, path: Path) -> None:
    """Stacked bars of the outcomes per kind."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    kinds = list(result["kinds"])
    fig, ax = plt.subplots(figsize=(7, 3))
    left = [0] * len(kinds)
    for outcome, colour in zip(OUTCOMES, ("tab:green", "tab:orange", "tab:red"), strict=True):
        counts = [result["kinds"][k][outcome] for k in kinds]
        ax.barh(kinds, counts, left=left, color=colour, label=outcome)
        left = [a + b for a, b in zip(left, counts, strict=True)]
    ax.set_xlabel("wrong inputs")
    ax.legend(loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def run_sweep(cases: Sequence[Case], out: Path, workers: int = 2, timeout: float = 60.0) -> dict:
    """Answer ``cases``, print the table and the cases not clear, write ``summary.json``,
    ``answers.jsonl`` and ``outcomes.png`` to ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    answers = sweep(cases, out / "scripts", workers, timeout)
    result = summary(answers)
    (out / "summary.json").write_text(json.dumps(result, indent=2))
    with open(out / "answers.jsonl", "w") as f:
        for a in answers:
            f.write(json.dumps(vars(a)) + "\n")
    plot(result, out / "outcomes.png")
    print(table(result))
    for a in result["not_clear"]:
        print(f"{a['outcome']:8s} {a['kind']:10s} {a['what']}  ->  {a['message'][:160]}")
    return result
