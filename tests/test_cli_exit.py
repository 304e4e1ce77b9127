"""Every command ends within 5 s of its last line (EXIT_S), through the installed entry points in
a process of its own, and nothing it started holds its output open after it: a build's worker
processes, a fit's DataLoader workers, also when SIGTERM stops the fit. `aigem paper`'s calls (a
build, a fit, the evaluations, the report) are timed alike in test_aigem_paper.py."""

from __future__ import annotations

import sys
from pathlib import Path

from timed_runs import AIGEM, NGSIM_GRAPHS, run_timed


def ngsim_graphs(*args: object) -> list[str]:
    return [sys.executable, "-c", NGSIM_GRAPHS, *map(str, args)]


def aigem(*args: object) -> list[str]:
    return [sys.executable, "-c", AIGEM, *map(str, args)]


def test_synth_build_with_worker_processes_and_stats_end_with_their_last_line(
    tmp_path: Path,
) -> None:
    raw, build = tmp_path / "raw", tmp_path / "build"
    calls = {
        "synth": ngsim_graphs("synth", raw, "--recordings", 2, "--minutes", 0.2, "--seed", 3),
        # Two recordings, two jobs: a pool of two worker processes.
        "build": ngsim_graphs("build", raw, "--out", build, "--d-sense-m", 12, "--jobs", 2),
        "stats": ngsim_graphs("stats", build),
    }
    for name, argv in calls.items():
        call = run_timed(argv)
        assert call.returncode == 0, (name, call.stderr)
        assert call.ended_with_its_last_line(), (name, call)


def fit_command(build: Path, run: Path, epochs: int) -> list[str]:
    """Two models trained together, with two DataLoader worker processes per loader."""
    options = ["--horizon-s", "1,2", "--batch-size", 16, "--workers", 2, "--threads", 1]
    return aigem("fit", build, "--out", run, "--epochs", epochs, *options, "--device", "cpu")


def test_a_fit_with_loader_workers_ends_with_its_last_line(
    tiny_build: Path, tmp_path: Path
) -> None:
    fit = run_timed(fit_command(tiny_build, tmp_path / "run", epochs=1))
    assert fit.returncode == 0, fit.stderr
    assert fit.ended_with_its_last_line(), fit


def test_a_fit_stopped_by_sigterm_ends_with_its_last_line_and_no_traceback(
    tiny_build: Path, tmp_path: Path
) -> None:
    # Stopped in its second epoch: both loaders' workers are running, a batch may be on its way.
    stopped = run_timed(fit_command(tiny_build, tmp_path / "run", epochs=3), stop_on="epoch 1:")
    assert stopped.returncode == 130, stopped.stderr
    assert stopped.stderr.splitlines()[-1].startswith("interrupted after epoch 1")
    # Workers ended by the interpreter's exit rather than with the fit sometimes printed a
    # ConnectionResetError from their resource_sharer thread (4 runs of 11).
    assert "Traceback" not in stopped.stderr
    assert stopped.ended_with_its_last_line(), stopped
