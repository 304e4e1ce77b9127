"""Benchmark: how long each command takes to end after its last line; the target is 5 s (EXIT_S),
on the CPU and on CUDA.

Each command runs through its installed entry point in a process of its own, on a tiny synthetic
input (not NGSIM) made in a temporary folder: synth; a build with two worker processes; stats; a
fit of two horizons with two DataLoader worker processes per loader; the same fit stopped by
SIGTERM in its second epoch; evaluate; `aigem paper --only table` for one epoch. For each it
prints its exit code, the seconds from its last line to its end, the seconds from its end to its
output's end (a process it started and left running holds that open), and whether both are
within the target. What once lingered: Inductor's compile workers (their shutdown waits up to
300 s), loader worker processes, pinned-memory threads.

    .venv/bin/python bench/bench_exit.py                 # the CPU
    .venv/bin/python bench/bench_exit.py --device cuda   # a GPU (bench/gpu_check.sh runs it)

The tests hold synth, build, stats and the two fits (tests/test_cli_exit.py, the same commands)
and `aigem paper`'s calls (tests/test_aigem_paper.py) to LINGER_S, a bound far above the target
that a busy machine passes.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from timed_runs import EXIT_S, TimedRun, aigem, ngsim_graphs, run_timed

STOPPED_CODE = 130  # a fit stopped by SIGTERM


def fit_command(build: Path, run: Path, epochs: int, device: str = "cpu") -> list[str]:
    """Two models trained together, with two DataLoader worker processes per loader."""
    options = ["--horizon-s", "1,2", "--batch-size", 16, "--workers", 2, "--threads", 1]
    return aigem("fit", build, "--out", run, "--epochs", epochs, *options, "--device", device)


def data_commands(folder: Path) -> dict[str, list[str]]:
    """Synth, a build with two worker processes and stats, into `folder` (raw/, build/)."""
    raw, build = folder / "raw", folder / "build"
    return {
        "synth": ngsim_graphs("synth", raw, "--recordings", 2, "--minutes", 0.2, "--seed", 3),
        # Two recordings, two jobs: a pool of two worker processes.
        "build": ngsim_graphs("build", raw, "--out", build, "--d-sense-m", 12, "--jobs", 2),
        "stats": ngsim_graphs("stats", build),
    }


def model_commands(folder: Path, device: str) -> dict[str, tuple[list[str], str | None]]:
    """The fit, the stopped fit (stopped on the text given), evaluate and `aigem paper` on the
    data that data_commands made in `folder`."""
    build, run = folder / "build", folder / "run"
    paper = ["--out", folder / "paper", "--only", "table", "--epochs", 1, "--batch-size", 64]
    return {
        "fit": (fit_command(build, run, 1, device), None),
        "fit stopped by SIGTERM": (fit_command(build, folder / "stopped", 3, device), "epoch 1:"),
        "evaluate": (aigem("evaluate", run, "--device", device), None),
        "paper --only table": (aigem("paper", folder / "raw", *paper, "--device", device), None),
    }


def ended_as_expected(name: str, call: TimedRun) -> bool:
    """Whether the command's exit code is the one it ends with (130 for the stopped fit)."""
    return call.returncode == (STOPPED_CODE if "SIGTERM" in name else 0)


def row(name: str, call: TimedRun) -> str:
    """One line of the table: the command, its exit code, its two times and the verdict."""
    code = f"{call.returncode}" + ("" if ended_as_expected(name, call) else " (!)")
    verdict = "yes" if call.ended_within(EXIT_S) else "NO"
    return (
        f"{name:<24}{code:>6}{call.after_last_line_s:>12.2f}{call.open_after_end_s:>12.2f}"
        f"{verdict:>9}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    args = parser.parse_args()
    header = f"{'command':<24}{'exit':>6}{'end (s)':>12}{'open (s)':>12}{f'<= {EXIT_S:g} s':>9}"
    print("end: its last line to its end; open: its end to its output's end")
    print(header, flush=True)
    calls, failed = [], []
    with tempfile.TemporaryDirectory(prefix="bench_exit_") as tmp:
        folder = Path(tmp)
        steps = {name: (argv, None) for name, argv in data_commands(folder).items()}
        for name, (argv, stop_on) in (steps | model_commands(folder, args.device)).items():
            call = run_timed(argv, stop_on=stop_on)
            calls.append(call)
            print(row(name, call), flush=True)
            if not ended_as_expected(name, call):
                failed.append(name)
                print(f"  its last error line: {call.stderr.strip().splitlines()[-1:]}")
    if failed:  # a command that failed measured nothing
        raise SystemExit(f"failed: {', '.join(failed)}; no figure")
    longest = max(max(c.after_last_line_s, c.open_after_end_s) for c in calls)
    within = all(call.ended_within(EXIT_S) for call in calls)
    print(f"longest end after a last line: {longest:.2f} s; all within {EXIT_S:g} s: {within}")


if __name__ == "__main__":
    main()
