"""Fuzz `ngsim-graphs build` with damaged small inputs of each raw format (issue 9).

Each case takes a small valid input (10 vehicles x 100 frames of us-101 0750am, as a portal CSV
with its quirks, a per-period CSV or a whitespace text file), damages it one way (seeded), runs
`ngsim-graphs build INPUT --out OUT` on it in a child process and sorts the outcome into:

- success: exit 0 and plausible: every row read is accounted for, the rows read are the data
  lines of the file, the tracks tables hold finite values within the physical limits, and
  there are samples;
- clean error: exit 1 or 2, nothing on stdout, one `error: ...` line on stderr that names the
  input (or --out), no output directory and nothing hidden left beside it;
- other: anything else (a traceback, a hang, a crash, a success that fails a check): a defect.

    python bench/fuzz_inputs.py [--seed 0] [--cases 381] [--jobs 2] [--keep DIR]

Prints a table of mutation kind x outcome, one line per "other" case, and exits 1 if there is
any. A case is reproduced by its seed, index, format and kind (`make_input`). Synthetic data.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import polars as pl

sys.path.insert(0, str(Path(__file__).parent))
from fuzz_mutations import (
    DEFAULT_CASES,
    FILE_NAMES,
    Case,
    count_data_lines,
    make_input,
    plan_cases,
)

from ngsim_graphs import schema as s
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.layout import manifest_path, read_manifest
from ngsim_graphs.sources.ngsim.plausibility import LIMITS  # the inputs are NGSIM's

SUCCESS, CLEAN_ERROR, OTHER = "success", "clean error", "other"
TIMEOUT_S = 60.0


# ---- running and classifying ---------------------------------------------------------------------


@dataclass(frozen=True)
class RunResult:
    returncode: int | None  # None: killed after the timeout (a hang)
    stdout: str
    stderr: str


@dataclass(frozen=True)
class Outcome:
    case: Case
    description: str
    status: str  # SUCCESS, CLEAN_ERROR or OTHER
    detail: str  # the error line, a success's counts, or what is wrong
    seconds: float


def cli_command() -> list[str]:
    """The installed `ngsim-graphs` beside this Python, else the same entry point via -c."""
    script = Path(sys.executable).with_name("ngsim-graphs")
    if script.is_file():
        return [str(script)]
    return [sys.executable, "-c", "from ngsim_cli.ngsim import main; main()"]


def run_build_process(input_path: Path, out: Path, timeout_s: float = TIMEOUT_S) -> RunResult:
    """`ngsim-graphs build INPUT --out OUT` in a child process (its own process group)."""
    env = {**os.environ, "COLUMNS": "200"}
    command = [*cli_command(), "build", str(input_path), "--out", str(out)]
    pipe = subprocess.PIPE
    child = subprocess.Popen(
        command, stdout=pipe, stderr=pipe, cwd=input_path.parent, env=env, start_new_session=True
    )
    try:
        stdout, stderr = child.communicate(timeout=timeout_s)
        code: int | None = child.returncode
    except subprocess.TimeoutExpired:
        os.killpg(child.pid, signal.SIGKILL)
        stdout, stderr = child.communicate()
        code = None
    return RunResult(code, stdout.decode(errors="replace"), stderr.decode(errors="replace"))


# A progress line off a terminal (cli.progress.PlainProgress after logs.TIMESTAMP):
# '2026-11-29 07:55:47 reading input files: 1/1 (100%), 0:00:00 elapsed'.
PROGRESS_LINE = re.compile(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d [^:]+: [\d,]+/[\d,]+ \(\d+%\), ")


def _lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.strip()]


_FRAME = re.compile(r'File "([^"]+)", line (\d+), in (\S+)|│ (\S+\.py):(\d+) in (\S+)')


def _traceback_summary(text: str) -> str:
    """The innermost frame of the project, the innermost frame and the exception of a traceback
    (plain, or drawn by rich as typer does)."""
    frames = [f"{m[1] or m[4]}:{m[2] or m[5]} in {m[3] or m[6]}" for m in _FRAME.finditer(text)]
    ours = [f for f in frames if "site-packages" not in f]
    lines = _lines(text)
    boxed = [i for i, line in enumerate(lines) if line.startswith("╰")]
    exception = lines[boxed[-1] + 1] if boxed and boxed[-1] + 1 < len(lines) else lines[-1]
    return " | ".join(dict.fromkeys([*ours[-1:], *frames[-1:], exception.strip()]))


def classify(run: RunResult, input_path: Path, out: Path, data: bytes, fmt: str) -> tuple[str, str]:
    """(status, detail) of one build of `input_path` (holding `data`) into `out`."""
    if run.returncode is None:
        return OTHER, f"hang: no exit within {TIMEOUT_S:g} s"
    if "Traceback" in run.stdout + run.stderr:
        return OTHER, "traceback: " + _traceback_summary(run.stdout + run.stderr)
    if run.returncode < 0:
        shown = " | ".join(_lines(run.stderr)[:3])
        return OTHER, f"crash: killed by signal {-run.returncode}; stderr: {shown}"
    left = sorted(p.name for p in out.parent.iterdir() if p.name not in (input_path.name, out.name))
    if left:
        return OTHER, f"left beside --out: {', '.join(left)}"
    if run.returncode == 0:
        problems = check_success(run, out, data, fmt)
        if problems:
            return OTHER, "exit 0 but " + "; ".join(problems)
        counts = read_manifest(out).counts
        return SUCCESS, f"{counts.rows_read} rows read, {counts.samples} samples"
    return classify_failure(run, input_path, out)


def classify_failure(run: RunResult, input_path: Path, out: Path) -> tuple[str, str]:
    """A failed build is a clean error only as one `error: ` line naming the input or --out."""
    lines = _lines(run.stderr)
    shown = " | ".join(lines[:3])
    if run.returncode not in (1, 2):
        return OTHER, f"exit status {run.returncode}: {shown}"
    if run.stdout.strip():
        return OTHER, f"a failed build printed on stdout: {' | '.join(_lines(run.stdout)[:3])}"
    if len(lines) != 1 or not lines[0].startswith("error: "):
        return OTHER, f"{len(lines)} lines on stderr, not one 'error: ' line: {shown}"
    if str(input_path) not in lines[0] and str(out) not in lines[0]:
        return OTHER, f"the error names neither the input nor --out: {lines[0]}"
    if out.exists():
        return OTHER, f"--out exists after a failed build: {lines[0]}"
    return CLEAN_ERROR, lines[0]


def check_success(run: RunResult, out: Path, data: bytes, fmt: str) -> list[str]:
    """What is implausible about a build that exited 0 (nothing: a plausible success)."""
    if not manifest_path(out).is_file():
        return ["no manifest.json"]
    try:
        counts = read_manifest(out).counts
    except NgsimInputError as err:
        return [f"its manifest cannot be read: {err}"]
    problems = [
        f"stderr line {line!r}"
        for line in _lines(run.stderr)
        if not line.startswith("warning: ") and not PROGRESS_LINE.match(line)
    ]
    if run.stdout.count("\n") == 0:
        problems.append("nothing on stdout")
    dropped = counts.rows_dropped
    before_cleaning = sum(
        n for reason, n in dropped.items() if reason != s.DropReason.POSITION_OUTLIER.value
    )
    accounted = (
        counts.rows_other_locations + counts.rows_missing_values + before_cleaning + counts.rows
    )
    read = counts.rows_read
    if read != accounted:
        problems.append(f"rows_read {read} but {accounted} accounted for (other locations, missing")
        problems[-1] += " values, dropped, kept)"
    visible, non_empty = count_data_lines(data, fmt)
    if not visible <= read <= non_empty:
        blank = f" (and {non_empty - visible} of spaces)" if non_empty != visible else ""
        problems.append(f"rows_read {read} but the file has {visible} data lines{blank}")
    duplicates = counts.exact_duplicates + counts.conflicting_duplicates
    cleaned = counts.rows - duplicates - dropped[s.DropReason.POSITION_OUTLIER.value]
    if not 0 <= counts.grid_rows <= cleaned:
        problems.append(
            f"grid_rows {counts.grid_rows} not within 0..{cleaned} (rows kept after cleaning)"
        )
    if counts.samples <= 0:
        problems.append("no samples")
    return problems + check_tracks(out, counts.grid_rows)


def check_tracks(out: Path, grid_rows: int) -> list[str]:
    """The tracks tables: as many rows as the manifest says, finite values within the limits."""
    paths = sorted((out / "tracks").glob("*.parquet"))
    if not paths:
        return ["no tracks tables"]
    tracks = pl.concat([pl.read_parquet(p) for p in paths])
    problems = []
    if tracks.height != grid_rows:
        problems.append(f"tracks tables hold {tracks.height} rows, counts.grid_rows {grid_rows}")
    floats = [name for name, dtype in tracks.schema.items() if dtype == pl.Float64]
    far = LIMITS.max_abs_position_m
    needed = pl.col(s.VEHICLE_ID, s.TRACK_ID, s.FRAME_ID, s.X_M, s.Y_M, s.SPEED_MPS)
    rules = {f"{name} not finite": ~pl.col(name).is_finite() for name in floats} | {
        "speed_mps outside [0, 70]": ~pl.col(s.SPEED_MPS).is_between(0, LIMITS.max_speed_mps),
        "|x_m| or |y_m| > 5000": (pl.col(s.X_M).abs() > far) | (pl.col(s.Y_M).abs() > far),
        "|accel_mps2| > 15": pl.col(s.ACCEL_MPS2).abs() > LIMITS.max_abs_accel_mps2,
        "frame_id < 0": pl.col(s.FRAME_ID) < 0,
        "null vehicle, track, frame, position or speed": pl.any_horizontal(needed.is_null()),
    }
    found = tracks.select(
        rule.fill_null(False).sum().alias(name) for name, rule in rules.items()
    ).row(0, named=True)
    return problems + [f"tracks: {n} rows with {name}" for name, n in found.items() if n]


def run_case(case: Case, work_root: Path, keep: Path | None = None) -> Outcome:
    """Mutate, build in a child process, classify; the case's folder is removed afterwards."""
    start = time.perf_counter()
    data, description = make_input(case)
    case_dir = work_root / f"case-{case.index:04d}"
    case_dir.mkdir(parents=True)
    input_path, out = case_dir / FILE_NAMES[case.fmt], case_dir / "out"
    input_path.write_bytes(data)
    run = RunResult(None, "", "")
    try:
        run = run_build_process(input_path, out)
        status, detail = classify(run, input_path, out, data, case.fmt)
    except (OSError, ValueError, KeyError, TypeError, pl.exceptions.PolarsError) as err:
        # a build whose output the checks cannot even read is a defect too
        status, detail = OTHER, f"checking the outcome failed: {type(err).__name__}: {err}"
    if status == OTHER and keep is not None:
        keep.mkdir(parents=True, exist_ok=True)
        stem = f"seed{case.seed}-case{case.index:04d}-{case.fmt}-{case.kind}"
        (keep / f"{stem}{input_path.suffix}").write_bytes(data)
        (keep / f"{stem}.log").write_text(
            f"{description}\n{detail}\n--- stdout\n{run.stdout}\n--- stderr\n{run.stderr}"
        )
    shutil.rmtree(case_dir, ignore_errors=True)
    return Outcome(case, description, status, detail, time.perf_counter() - start)


def run_cases(
    cases: list[Case],
    work_root: Path,
    jobs: int = 2,
    keep: Path | None = None,
    on_done: Callable[[int], None] | None = None,
) -> list[Outcome]:
    """Every case, `jobs` at a time; outcomes in case order."""
    work_root = work_root.resolve()  # the reader names files by their resolved path
    with ThreadPoolExecutor(max_workers=max(1, jobs)) as pool:
        futures = [pool.submit(run_case, case, work_root, keep) for case in cases]
        outcomes = []
        for done, future in enumerate(futures, 1):
            outcomes.append(future.result())
            if on_done:
                on_done(done)
    return outcomes


# ---- the report ------------------------------------------------------------------------------------


def format_table(rows: list[list[str]]) -> str:
    """Plain aligned columns: the first left-aligned, the rest right-aligned."""
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    return "\n".join(
        "  ".join(
            cell.ljust(w) if i == 0 else cell.rjust(w)
            for i, (cell, w) in enumerate(zip(row, widths, strict=False))
        )
        for row in rows
    )


def outcome_table(outcomes: list[Outcome], key: Callable[[Outcome], str], title: str) -> str:
    statuses = (SUCCESS, CLEAN_ERROR, OTHER)
    groups = list(dict.fromkeys(key(o) for o in outcomes))
    rows = [[title, *statuses, "total"]]
    for group in [*groups, "all"]:
        mine = [o for o in outcomes if group == "all" or key(o) == group]
        rows.append(
            [group, *(str(sum(o.status == st for o in mine)) for st in statuses), str(len(mine))]
        )
    return format_table(rows)


def describe_others(outcomes: list[Outcome]) -> str:
    """One entry per "other" outcome: how to repeat it, what was done, what happened."""
    return "\n".join(
        f"seed {o.case.seed} case {o.case.index} {o.case.fmt} {o.case.kind}: {o.description}"
        f"\n    -> {o.detail}"
        for o in outcomes
        if o.status == OTHER
    )


def report(outcomes: list[Outcome], seconds: float) -> str:
    others = describe_others(outcomes)
    parts = [
        outcome_table(outcomes, lambda o: o.case.kind, "mutation"),
        outcome_table(outcomes, lambda o: o.case.fmt, "format"),
        f"other (defects):\n{others}" if others else "other (defects): none",
        f"{len(outcomes)} cases in {seconds:.1f} s",
    ]
    return "\n\n".join(parts)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--cases", type=int, default=DEFAULT_CASES)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument(
        "--keep", type=Path, default=None, help="Folder to keep the inputs of 'other' cases in."
    )
    parser.add_argument("--verbose", action="store_true", help="Also print one line per case.")
    args = parser.parse_args(argv)
    cases = plan_cases(args.seed, args.cases)
    start = time.perf_counter()

    def progress(done: int) -> None:
        if done % 50 == 0 or done == len(cases):
            print(
                f"  {done}/{len(cases)} cases, {time.perf_counter() - start:.0f} s",
                file=sys.stderr,
                flush=True,
            )

    with tempfile.TemporaryDirectory(prefix="ngsim-fuzz-") as work:
        outcomes = run_cases(cases, Path(work), args.jobs, args.keep, progress)
    if args.verbose:
        for o in outcomes:
            case = f"{o.case.index:4d} {o.case.fmt:6} {o.case.kind:20}"
            print(f"{case} {o.status:11} {o.description} -> {o.detail}")
    print(report(outcomes, time.perf_counter() - start))
    return 1 if any(o.status == OTHER for o in outcomes) else 0


if __name__ == "__main__":
    sys.exit(main())
