"""Benchmark: `evaluate` (an older checkout's `evaluate_horizons`) of a multi-horizon run, two checkouts side by side.

Each measurement is one fresh process that imports `aigem` from one checkout (its root first on
sys.path) and times one `evaluate(RUN)` call on the CPU: the models' loading, the split
and the scoring, not Python's or PyTorch's import. The checkouts alternate (old new, new old,
...), so that a busy machine slows both alike; the script prints each call's samples/s (test
samples scored by all the run's models, per second of the call), the median of each and the
ratio of each round's pair. It also prints the largest difference between the metrics the two
give, the model's and constant velocity's rows (the model's differ by float rounding).

`--command` times the whole command instead: `aigem evaluate RUN --device cpu` of each checkout
in a fresh process, from its start to its end (Python's start and the imports included), with
`OMP_NUM_THREADS` set to --threads; it prints each call's seconds and their ratio.

`--forward` adds where the time goes, in this process with this checkout's code: the test batches
loaded once, then the models' forward passes over them, as one stacked ensemble (what evaluate
runs on an accelerator) and one model after the other (what it runs on the CPU), alternating.

    mkdir -p bench/out/ev/old && git archive 7610a76 | tar -x -C bench/out/ev/old   # before one pass
    .venv/bin/python bench/bench_evaluate.py bench/out/ev/run --old bench/out/ev/old --new . --rounds 6
    .venv/bin/python bench/bench_evaluate.py bench/out/ev/run --old bench/out/ev/old --new . --command

Make the run with `ngsim-graphs synth`, `ngsim-graphs build` and `aigem fit --horizon-s
1,2,3,4,5` (docs/benchmarks.md has the commands). Synthetic data: these are not NGSIM results.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

# One measurement, in a child process: argv = checkout, run directory, threads.
CHILD = """
import json, sys, time
from pathlib import Path
sys.path.insert(0, sys.argv[1])
import torch
torch.set_num_threads(int(sys.argv[3]))
import aigem.evaluation.evaluate as evaluation
from aigem.evaluation.results import as_dict
start = time.perf_counter()
score = getattr(evaluation, "evaluate_horizons", evaluation.evaluate)  # an older checkout's name
result = score(Path(sys.argv[2]), None, "test", "cpu")
seconds = time.perf_counter() - start
print(json.dumps({"module": evaluation.__file__, "seconds": seconds, "result": as_dict(result)}))
"""


# The whole command, in a child process: argv = checkout, run directory. The checkout's CLI (cli/)
# is imported as the package `ngsim_cli` it installs as; its aigem and ngsim_graphs come first on
# sys.path. Its last line names the aigem it ran.
COMMAND = """
import importlib.util, sys
from pathlib import Path
root = Path(sys.argv[1]).resolve()
sys.path.insert(0, str(root))
spec = importlib.util.spec_from_file_location(
    "ngsim_cli", root / "cli" / "__init__.py", submodule_search_locations=[str(root / "cli")]
)
sys.modules["ngsim_cli"] = package = importlib.util.module_from_spec(spec)
spec.loader.exec_module(package)
from ngsim_cli.entry import aigem
sys.argv = ["aigem", "evaluate", sys.argv[2], "--device", "cpu"]
try:
    aigem()
except SystemExit as end:
    code = end.code
else:
    code = 0
print("aigem:", sys.modules["aigem"].__file__, flush=True)
sys.exit(code)
"""


def measure_command(checkout: Path, run: Path, threads: int) -> float:
    """Seconds of `aigem evaluate RUN` by `checkout`'s code, a fresh process from start to end."""
    environment = {**os.environ, "OMP_NUM_THREADS": str(threads)}
    start = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-c", COMMAND, str(checkout), str(run)],
        capture_output=True,
        text=True,
        env=environment,
    )
    seconds = time.perf_counter() - start
    if done.returncode != 0:
        raise SystemExit(f"{checkout}: aigem evaluate failed:\n{done.stderr}")
    module = Path(done.stdout.strip().splitlines()[-1].removeprefix("aigem: "))
    if not module.is_relative_to(checkout.resolve()):
        raise SystemExit(f"ran {module}, not {checkout}'s aigem")
    return seconds


def measure(checkout: Path, run: Path, threads: int) -> dict:
    """One evaluation of `run` by `checkout`'s code, in a fresh process."""
    done = subprocess.run(
        [sys.executable, "-c", CHILD, str(checkout.resolve()), str(run), str(threads)],
        capture_output=True,
        text=True,
    )
    if done.returncode != 0:
        raise SystemExit(f"{checkout}: the evaluation failed:\n{done.stderr}")
    measured = json.loads(done.stdout.strip().splitlines()[-1])
    if not Path(measured["module"]).is_relative_to(checkout.resolve()):
        raise SystemExit(f"imported {measured['module']}, not {checkout}'s aigem")
    return measured


def largest_difference(ours: object, theirs: object) -> float:
    """The largest absolute difference between two JSON documents' numbers (inf where their
    shapes or non-numbers differ)."""
    if isinstance(ours, dict) and isinstance(theirs, dict) and ours.keys() == theirs.keys():
        return max((largest_difference(ours[k], theirs[k]) for k in ours), default=0.0)
    if isinstance(ours, list) and isinstance(theirs, list) and len(ours) == len(theirs):
        return max(
            (largest_difference(a, b) for a, b in zip(ours, theirs, strict=True)), default=0.0
        )
    numbers = (int, float)
    if isinstance(ours, numbers) and isinstance(theirs, numbers) and not isinstance(ours, bool):
        return abs(float(ours) - float(theirs))
    return 0.0 if ours == theirs else float("inf")


def forward_times(run: Path, rounds: int) -> None:
    """Seconds of loading the test split's batches once, then of the run's models' forward passes
    over them, as one stacked ensemble and one model after the other, each round alternating.
    The installed aigem's code (this checkout's, in its .venv)."""
    import torch
    from torch.utils.data import DataLoader

    from aigem.evaluation.evaluate import load_run
    from aigem.model.data import Collate, GraphDataset
    from aigem.runs.records import member_dir, read_horizons
    from aigem.training.ensemble import stack

    runs = [
        load_run(member_dir(run, h), None, torch.device("cpu"), False) for h in read_horizons(run)
    ]
    config = runs[0].model.config
    dataset = GraphDataset(runs[0].build_dir, "test", config.history_steps_read, runs[0].scaler)
    start = time.perf_counter()
    collate = Collate(dataset.scaler, layers=config.layers)
    batches = list(DataLoader(dataset, batch_size=64, collate_fn=collate))
    print(
        f"loading the test split once ({len(batches)} batches): {time.perf_counter() - start:.2f} s"
    )
    steps = [loaded.steps(dataset) for loaded in runs]
    ensemble = stack([loaded.model for loaded in runs], steps)
    ensemble.eval()
    with torch.no_grad():
        for round_index in range(rounds):
            start = time.perf_counter()
            for batch in batches:
                ensemble(batch)
            stacked = time.perf_counter() - start
            start = time.perf_counter()
            for batch in batches:
                for loaded, k in zip(runs, steps, strict=True):
                    loaded.model(batch, k)
            apart = time.perf_counter() - start
            print(f"forward, round {round_index + 1}: stacked {stacked:.2f} s, apart {apart:.2f} s")


def compare_commands(args: argparse.Namespace) -> None:
    """Each round's seconds of the whole command by both checkouts, alternating, and the ratios."""
    seconds: dict[str, list[float]] = {"old": [], "new": []}
    for round_index in range(args.rounds):
        for name in ("old", "new") if round_index % 2 == 0 else ("new", "old"):
            seconds[name].append(measure_command(getattr(args, name), args.run, args.threads))
            print(f"round {round_index + 1} {name}: aigem evaluate in {seconds[name][-1]:.2f} s")
    old, new = (statistics.median(seconds[name]) for name in ("old", "new"))
    ratios = [o / n for o, n in zip(seconds["old"], seconds["new"], strict=True)]
    print(f"median seconds: old {old:.2f}, new {new:.2f}; old / new {old / new:.2f}")
    print(f"old / new per round: {', '.join(f'{r:.2f}' for r in ratios)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a multi-horizon run (aigem fit --horizon-s ...)")
    parser.add_argument("--old", type=Path, required=True, help="the checkout to compare with")
    parser.add_argument("--new", type=Path, default=Path("."), help="this checkout (default .)")
    parser.add_argument("--rounds", type=int, default=5, help="calls of each, alternating")
    parser.add_argument("--threads", type=int, default=1, help="torch's CPU threads")
    parser.add_argument("--forward", action="store_true", help="also time the forward passes")
    parser.add_argument("--command", action="store_true", help="time the whole aigem evaluate")
    args = parser.parse_args()
    if args.command:
        compare_commands(args)
        return
    rates: dict[str, list[float]] = {"old": [], "new": []}
    results: dict[str, dict] = {}
    for round_index in range(args.rounds):
        for name in ("old", "new") if round_index % 2 == 0 else ("new", "old"):
            measured = measure(getattr(args, name), args.run, args.threads)
            samples = measured["result"]["samples"]
            rates[name].append(samples / measured["seconds"])
            results[name] = measured["result"]
            print(
                f"round {round_index + 1} {name}: {samples} samples x "
                f"{len(measured['result']['horizons_s'])} models in {measured['seconds']:.1f} s, "
                f"{rates[name][-1]:.1f} samples/s",
                flush=True,
            )
    old, new = (statistics.median(rates[name]) for name in ("old", "new"))
    ratios = [n / o for o, n in zip(rates["old"], rates["new"], strict=True)]
    print(f"median samples/s: old {old:.1f}, new {new:.1f}; ratio {new / old:.2f}")
    print(f"ratio per round: {', '.join(f'{r:.2f}' for r in ratios)}")
    rows = ("model", "constant_velocity")  # what both report (newer code reports more)
    difference = largest_difference(*({k: results[n][k] for k in rows} for n in ("old", "new")))
    print(f"largest difference between the two results' metrics: {difference:.3g}")
    if args.forward:
        import torch

        torch.set_num_threads(args.threads)
        forward_times(args.run, args.rounds)


if __name__ == "__main__":
    main()
