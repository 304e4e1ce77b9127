"""Benchmark: the CPU five-horizon fit loop of this tree beside `--against REV`'s, side by side.

Each round fits the five horizons' models for one epoch on BUILD (batch 32, one thread, no
loader workers) with the code of REV and with this tree, each in a fresh process
(`fit_once.py`, the checkout on PYTHONPATH; REV checked out once as a git worktree under
bench/out), the order alternating from round to round (the second of a pair tends to run a few
per cent faster). Prints each fit's graphs/s (fit's own figure for its training loop) and the
median of this tree's over REV's, per round and in all, and checks that both trained the same
models (the same validation losses and weights' digest). Synthetic data: not NGSIM results.

    python bench/bench_fit_loop.py BUILD                    # against 66e4b70, 5 rounds
    python bench/bench_fit_loop.py BUILD --against HEAD~1 --rounds 3
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

from bench_build import ROOT, checkout


def fit_once(code: Path, build: Path) -> dict:
    """One fit by the checkout at `code` in a process of its own (fit_once.py)."""
    command = [sys.executable, str(Path(__file__).with_name("fit_once.py")), str(build)]
    environment = dict(os.environ, PYTHONPATH=str(code))
    done = subprocess.run(command, env=environment, capture_output=True, text=True)
    if done.returncode:
        raise SystemExit(f"the fit of {code} failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("build", type=Path)
    parser.add_argument("--against", default="66e4b70", help="the revision to compare with")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--work-dir", type=Path, default=ROOT / "bench" / "out")
    args = parser.parse_args()
    codes = [checkout(args.against, args.work_dir), ROOT]
    ratios, seen = [], {}
    for round_index in range(args.rounds):
        order = codes if round_index % 2 == 0 else codes[::-1]
        fits = {code: fit_once(code, args.build) for code in order}
        for code in order:
            figures = fits[code]
            seen.setdefault(code, []).append(figures["graphs_per_s"])
            print(
                f"round {round_index + 1}  {code.name:<12} {figures['graphs_per_s']:6.1f} graphs/s"
            )
        base, this = fits[codes[0]], fits[codes[1]]
        if (base["weights"], base["val_loss_m2"]) != (this["weights"], this["val_loss_m2"]):
            raise SystemExit("the two checkouts trained other models: no comparison")
        ratios.append(this["graphs_per_s"] / base["graphs_per_s"])
    print(f"same models: weights {base['weights']}, validation losses {base['val_loss_m2']}")
    for code in codes:
        label = args.against if code != ROOT else "this tree"
        print(f"  {label:<12} median {statistics.median(seen[code]):.1f} graphs/s")
    print(
        f"  this tree / {args.against}: {statistics.median(ratios):.3f} of its speed (median of "
        f"{', '.join(f'{r:.3f}' for r in ratios)})"
    )


if __name__ == "__main__":
    main()
