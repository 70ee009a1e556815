"""Try wrong inputs as a user would, over the Python API and the scripts, and count the
answers: clear (refused, the message names what is wrong), unclear, silent (accepted).

python scripts/sweep_wrong_inputs.py                  # every case: about 10 minutes on 2 cores
python scripts/sweep_wrong_inputs.py --only api       # the Python API alone: about 2 minutes
"""

import argparse
from pathlib import Path

from vistask.cli import positive_int, run_main
from vistask.experiments.wrong_input_cases import api_cases
from vistask.experiments.wrong_input_scripts import script_cases
from vistask.experiments.wrong_inputs import run_sweep
from vistask.runs import run_dir


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--only", choices=("api", "scripts"), default=None)
    parser.add_argument("--workers", type=positive_int, default=2, help="scripts side by side")
    parser.add_argument(
        "--timeout",
        type=positive_int,
        default=60,
        help="seconds after which a script still working counts as accepted",
    )
    parser.add_argument("--out", default=None, help="default runs/sweep_wrong_inputs-<time>")
    args = parser.parse_args()
    out = run_dir("sweep_wrong_inputs", args.out)
    cases = []
    if args.only != "scripts":
        cases += api_cases(Path(out) / "files")
    if args.only != "api":
        cases += script_cases()
    run_sweep(cases, Path(out), args.workers, args.timeout)


if __name__ == "__main__":
    run_main(main)
