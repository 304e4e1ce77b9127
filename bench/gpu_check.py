"""Measure a machine for the training engine's targets (docs/benchmarks.md), from raw files to a
table of the target figures, printed last. `bench/gpu_check.sh` installs the project first where
it is missing (from wheels carried beside it, with no network) and runs this.

    bench/gpu_check.sh                                  # a GPU machine: about 6-7 minutes
    bench/gpu_check.sh --accuracy-epochs 10 --deadline-s 560   # and the CUDA defaults' figures
    bench/gpu_check.sh --device cpu --recordings 1 --minutes 0.4 --epochs 1 --batch-size 8 \\
        --bench-sizes 8 --steps 1 --fast                # the CPU, a tiny input (the test's)

Stages, each timed and bounded (a stage that fails or runs out of time is reported, and the
table says what it could not measure):
0. tests: tests/test_aigem_engine.py, whose captured steps (CUDA only) must equal eager ones;
1. synth: `ngsim-graphs synth` of --recordings periods of --minutes (synthetic, not NGSIM);
2. build: `ngsim-graphs build` with --jobs workers;
3. bench: `bench/bench_train.py` at batch 32 and --batch-size, one and five models (the model
   step, the static step, fit's loop on static batches: graphs/s, launches and syncs a step);
4. fit: `aigem fit --horizon-s 1,2,3,4,5` for --epochs epochs at --batch-size, with nvidia-smi's
   GPU utilisation sampled every 0.5 s from the end of its first epoch to its end;
5. evaluate: that run scored on the test split (`aigem.evaluation.evaluate.evaluate`);
6. exit: `bench/bench_exit.py` on a tiny input of its own, how long each command (synth, build,
   stats, fit, a fit stopped by SIGTERM, evaluate, `aigem paper --only table`) takes to end
   after its last line;
7. paper: `aigem paper --only table` for --epochs epochs at --batch-size; its time per stage,
   and the paper's protocol (100 epochs, the four fits) extrapolated from it to the six
   15-minute recordings (79,504 train graphs): per epoch times 100 and the train graphs' ratio;
8. with --accuracy-epochs N (N > 0), `bench/bench_accuracy.py` on the build: ACCURACY_SETTINGS
   for N epochs each, the 5 s model, to constant velocity's validation loss (the fit's
   baseline.json): the figures that choose the GPU's default batch, rate and schedule.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

PAPER_EPOCHS = 100  # the paper's protocol
PAPER_FITS = 4  # aigem paper's fits: d_min 25 with and without concatenation, d_min 0, d_min 50
FULL_TRAIN_GRAPHS = 79_504  # the six 15-minute synthetic recordings' train split
HORIZONS = "1,2,3,4,5"


ACCURACY_SETTINGS = (  # the paper's batch, and two larger ones with their rates warmed up and decayed
    "batch=32",
    "batch=256,lr=3e-3,schedule=cosine,warmup=1",
    "batch=1024,lr=6e-3,schedule=cosine,warmup=2",
)


class Stages:
    """Runs the stages, keeps what each measured and how long it took."""

    def __init__(self, deadline_s: float) -> None:
        self.start, self.deadline_s = time.monotonic(), deadline_s
        self.seconds: dict[str, float] = {}
        self.failed: dict[str, str] = {}

    def left_s(self) -> float:
        return self.deadline_s - (time.monotonic() - self.start)

    def run(self, name: str, command: list[str], share: float = 1.0) -> str | None:
        """Run `command` (its output echoed), bounded by `share` of the time left; its stdout,
        or None where it failed."""
        timeout = max(10.0, share * self.left_s())
        print(f"\n== {name}: {' '.join(command)}  (at most {timeout:.0f} s)", flush=True)
        began = time.monotonic()
        # A session of its own: past its time the stage is killed with every process it started.
        process = subprocess.Popen(
            command,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            start_new_session=True,
        )
        try:
            stdout, stderr = process.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.communicate()
            self.failed[name] = f"stopped after {timeout:.0f} s"
            return None
        finally:
            self.seconds[name] = time.monotonic() - began
        print(stdout, end="")
        noise = ("profiler_start", "profiler_stop")  # Kineto's lines
        kept = [line for line in stderr.splitlines(True) if not line.rstrip().endswith(noise)]
        print("".join(kept)[-4000:], end="", file=sys.stderr)
        if process.returncode != 0:
            self.failed[name] = f"exit {process.returncode}"
            return None
        return stdout


def parse_table(text: str) -> dict[tuple[str, str, str], dict[str, str]]:
    """bench_train's rows by (device, batch, measured) -> {column: value}."""
    lines = [line for line in text.splitlines() if line.strip()]
    header = next((i for i, line in enumerate(lines) if line.startswith("device")), None)
    if header is None:
        return {}
    split = lambda line: [cell.strip() for cell in line.split("  ") if cell.strip()]  # noqa: E731
    names = split(lines[header])
    rows = {}
    for line in lines[header + 1 :]:
        cells = split(line)
        if len(cells) >= 3:
            rows[tuple(cells[:3])] = dict(zip(names, cells, strict=False))
    return rows


class Sampler:
    """nvidia-smi's GPU utilisation every 0.5 s, with the time of each sample; nothing where
    there is no nvidia-smi."""

    def __init__(self) -> None:
        self.samples: list[tuple[float, float]] = []
        self.process = None
        if shutil.which("nvidia-smi"):
            query = ["nvidia-smi", "--query-gpu=utilization.gpu", "--format=csv,noheader,nounits"]
            self.process = subprocess.Popen(
                [*query, "-lms", "500"], stdout=subprocess.PIPE, text=True
            )
            threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.process.stdout:
            try:
                self.samples.append((time.monotonic(), float(line.strip().split(",")[0])))
            except ValueError:
                continue

    def stop(self) -> None:
        if self.process is not None:
            self.process.terminate()
            self.process.wait(timeout=5)

    def mean_since(self, start: float) -> float | None:
        values = [value for at, value in self.samples if at >= start]
        return sum(values) / len(values) if values else None


def fit_with_sampling(stages: Stages, command: list[str]) -> float | None:
    """Run the fit, sampling the GPU from the end of its first epoch (the splits loaded, the
    steps captured) to its end: the mean utilisation of its later epochs, their validation and
    checkpoints included."""
    print(f"\n== fit: {' '.join(command)}", flush=True)
    sampler, began, training_from = Sampler(), time.monotonic(), None
    process = subprocess.Popen(command, stderr=subprocess.PIPE, text=True)
    timer = threading.Timer(max(10.0, 0.5 * stages.left_s()), process.kill)
    timer.start()
    for line in process.stderr:
        print(line, end="", file=sys.stderr)
        if training_from is None and "epoch 1:" in line:
            training_from = time.monotonic()
    process.wait()
    timer.cancel()
    sampler.stop()
    stages.seconds["fit"] = time.monotonic() - began
    if process.returncode != 0:
        stages.failed["fit"] = f"exit {process.returncode}"
    return sampler.mean_since(training_from) if training_from is not None else None


def epoch_seconds(run: Path) -> tuple[float, int] | None:
    """(train + validation seconds of an epoch, the epoch's train graphs) of a five-horizon run,
    the mean over its epochs after the first (which captures the steps), or its first."""
    from aigem.runs.run_log import read_metrics

    rows = read_metrics(run / "h5s")
    if not rows:
        return None
    later = rows[1:] or rows
    seconds = sum(row.train_seconds + row.val_seconds for row in later) / len(later)
    return seconds, rows[0].train_graphs


def evaluate_rate(run: Path, device: str) -> tuple[float, float] | None:
    """(seconds, test samples a second per model) of the run's evaluation, in this process."""
    from aigem.evaluation.evaluate import evaluate

    began = time.monotonic()
    result = evaluate(run, None, "test", device)
    seconds = time.monotonic() - began
    return seconds, result.samples * len(result.horizons_s) / seconds


def paper_estimate(paper: Path, epochs: int) -> dict[str, float] | None:
    """The paper's protocol in minutes on the six 15-minute recordings, from a run of `epochs`
    epochs of its table's fit: builds as measured; each of PAPER_FITS fits its start-up plus
    PAPER_EPOCHS epochs; each evaluation as measured; all scaled by the train graphs' ratio."""
    report = paper / "report.json"
    if not report.is_file():
        return None
    timings = json.loads(report.read_text())["timings"]
    fit_s = timings.get("fit dmin-25m")
    per_epoch = epoch_seconds(paper / "runs" / "dmin-25m")
    if fit_s is None or per_epoch is None:
        return None
    epoch_s, graphs = per_epoch
    start_s = max(0.0, fit_s - epochs * epoch_s)
    scale = FULL_TRAIN_GRAPHS / graphs
    evaluate_s = timings.get("evaluate dmin-25m", 0.0)
    builds_s = 3 * timings.get("builds", 0.0)  # three builds; run_builds shares their reading
    total = builds_s + PAPER_FITS * (start_s + PAPER_EPOCHS * epoch_s + evaluate_s)
    return {"minutes": total * scale / 60, "epoch_s": epoch_s * scale, "scale": scale}


def longest_exit_s(text: str) -> float | None:
    """bench_exit's longest time from a command's last line to its end (or its output's)."""
    found = re.search(r"longest end after a last line: ([0-9.]+|inf) s", text)
    return float(found.group(1)) if found else None


def _number(row: dict[str, str] | None, column: str) -> float | None:
    value = (row or {}).get(column, "-")
    try:
        return float(value.replace(",", "").rstrip("%"))
    except ValueError:
        return None


def _cell(value: float | None, digits: int = 0) -> str:
    return "-" if value is None else f"{value:,.{digits}f}"


def summary(device: str, batch: int, rows: dict, measured: dict) -> list[tuple[str, str, str]]:
    """(figure, target, measured) of the table printed last."""
    row = lambda size, what: rows.get((device, str(size), what))  # noqa: E731
    gpu = device == "cuda"
    lines = [
        (f"fit loop, 5 horizons, batch {batch} (graphs/s)", ">= 20,000",
         _cell(_number(row(batch, "fit 5 h st" if gpu else "fit 5 h"), "graphs/s"))),
        (f"fit loop, 1 model, batch {batch} (graphs/s)", ">= 30,000",
         _cell(_number(row(batch, "fit loop st" if gpu else "fit loop"), "graphs/s"))),
        ("fit loop, 5 horizons, batch 32 (graphs/s)", "(415 at 7610a76)",
         _cell(_number(row(32, "fit 5 h st" if gpu else "fit 5 h"), "graphs/s"))),
        (f"static step, 5 models, batch {batch} (graphs/s)", "-",
         _cell(_number(row(batch, "static 5"), "graphs/s"))),
        (f"launches a step, 5 models, batch {batch}", "a few (2,390 at 7610a76)",
         _cell(_number(row(batch, "static 5"), "launches/step"), 1)),
        (f"syncs a step, fit loop, 5 horizons, batch {batch}", "0",
         _cell(_number(row(batch, "fit 5 h st" if gpu else "fit 5 h"), "syncs/step"), 1)),
        ("GPU busy while the 5-horizon fit trains (%)", ">= 80", _cell(measured.get("busy"))),
        ("fit epoch, 5 horizons, measured input (s)", "-", _cell(measured.get("epoch_s"), 1)),
        ("evaluate (test samples/s per model)", ">= 50,000", _cell(measured.get("evaluate"))),
        ("aigem paper, full protocol, six 15-min recordings (min, extrapolated)", "<= 30",
         _cell(measured.get("paper_minutes"), 1)),
        ("longest end of a command after its last line (s, bench_exit.py)", "<= 5",
         _cell(measured.get("exit_s"), 2)),
        ("captured steps equal eager ones (tests/test_aigem_engine.py)", "passed",
         measured.get("tests", "-")),
    ]  # fmt: skip
    return lines


def main() -> None:
    from aigem.cores import default_workers
    from ngsim_graphs.budget import available_cores

    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--device", choices=("cuda", "cpu"), default="cuda")
    parser.add_argument("--out", type=Path, default=Path("/tmp/gpu_check"))
    parser.add_argument("--recordings", type=int, default=6)
    parser.add_argument("--minutes", type=float, default=6.0)
    parser.add_argument("--epochs", type=int, default=4, help="of the fit and of aigem paper")
    parser.add_argument("--batch-size", type=int, default=1024, help="beside 32")
    parser.add_argument("--steps", type=int, default=20, help="bench_train's timed steps")
    parser.add_argument(
        "--bench-sizes",
        default=None,
        help="bench_train's batch sizes (default: 32 and --batch-size)",
    )
    parser.add_argument("--jobs", type=int, default=None, help="build and loader workers")
    parser.add_argument("--deadline-s", type=float, default=450.0, help="the whole check's")
    parser.add_argument("--fast", action="store_true", help="bench_train: 1 warm-up step")
    parser.add_argument(
        "--accuracy-epochs", type=int, default=0, help="bench_accuracy's epochs (0: not run)"
    )
    args = parser.parse_args()
    if args.out.exists():
        shutil.rmtree(args.out)
    args.out.mkdir(parents=True)
    stages, measured = Stages(args.deadline_s), {}
    raw, build, run = args.out / "raw", args.out / "build", args.out / "run"
    workers = ["--workers", str(args.jobs)] if args.jobs is not None else []
    tests = Path(__file__).resolve().parents[1] / "tests" / "test_aigem_engine.py"
    # in this process (pyproject's addopts ask for pytest-xdist, which a device may not have)
    checked = stages.run("tests", [sys.executable, "-m", "pytest", "-o", "addopts=", "-q", "-p",
                                   "no:cacheprovider", "-rs", str(tests)], 0.15)  # fmt: skip
    measured["tests"] = "passed" if checked is not None else "FAILED"
    stages.run("synth", ["ngsim-graphs", "synth", str(raw), "--recordings", str(args.recordings),
                         "--minutes", str(args.minutes)])  # fmt: skip
    jobs = ["--jobs", str(args.jobs)] if args.jobs is not None else []
    stages.run("build", ["ngsim-graphs", "build", str(raw), "--out", str(build), *jobs], 0.3)
    warmup = ["--warmup", "1", "--profile-steps", "1"] if args.fast else []
    # fit's own default on this device (a GPU: all cores but two, at most 12), as 7610a76's figures
    loader_workers = (
        args.jobs if args.jobs is not None else default_workers(args.device, available_cores())
    )
    sizes = args.bench_sizes or ("32" if args.batch_size == 32 else f"32,{args.batch_size}")
    bench = stages.run("bench", [sys.executable, str(Path(__file__).parent / "bench_train.py"),
                                 str(build), "--device", args.device, "--batch-sizes", sizes,
                                 "--models", "5", "--steps", str(args.steps), *warmup,
                                 "--workers", str(loader_workers)], 0.4)  # fmt: skip
    rows = parse_table(bench or "")
    measured["busy"] = fit_with_sampling(
        stages,
        ["aigem", "fit", str(build), "--out", str(run), "--horizon-s", HORIZONS,
         "--epochs", str(args.epochs), "--batch-size", str(args.batch_size),
         "--device", args.device, *workers],
    )  # fmt: skip
    if (run / "h5s" / "metrics.jsonl").is_file():
        per_epoch = epoch_seconds(run)  # None: the file holds no epoch yet
        measured["epoch_s"] = per_epoch[0] if per_epoch else None
        try:
            seconds, measured["evaluate"] = evaluate_rate(run, args.device)
            stages.seconds["evaluate"] = seconds
        except Exception as err:  # the table says what failed
            stages.failed["evaluate"] = f"{type(err).__name__}: {err}"
    exits = stages.run("exit", [sys.executable, str(Path(__file__).parent / "bench_exit.py"),
                                "--device", args.device], 0.25)  # fmt: skip
    measured["exit_s"] = longest_exit_s(exits or "")
    paper = args.out / "paper"
    stages.run("paper", ["aigem", "paper", str(raw), "--out", str(paper), "--only", "table",
                         "--epochs", str(args.epochs), "--batch-size", str(args.batch_size),
                         "--device", args.device, *jobs], 0.9)  # fmt: skip
    estimate = paper_estimate(paper, args.epochs)
    measured["paper_minutes"] = estimate["minutes"] if estimate else None
    from aigem.runs.run_log import read_baseline

    target = read_baseline(run / "h5s")
    if args.accuracy_epochs > 0 and target is not None:
        settings = [part for setting in ACCURACY_SETTINGS for part in ("--setting", setting)]
        stages.run("accuracy", [sys.executable, str(Path(__file__).parent / "bench_accuracy.py"),
                                str(build), "--out", str(args.out / "accuracy"), *settings,
                                "--epochs", str(args.accuracy_epochs), "--target-m2", f"{target:.4f}",
                                "--device", args.device, *workers], 0.95)  # fmt: skip
    print_table(args, stages, rows, measured)


def print_table(args: argparse.Namespace, stages: Stages, rows: dict, measured: dict) -> None:
    import torch

    card = torch.cuda.get_device_name() if args.device == "cuda" else "the CPU"
    print(f"\n== gpu_check on {card}: {args.recordings} synthetic recordings of "
          f"{args.minutes:g} min, batch {args.batch_size}, {args.epochs} epochs")  # fmt: skip
    stage_times = ", ".join(f"{name} {s:.0f} s" for name, s in stages.seconds.items())
    print(f"stages: {stage_times}; total {time.monotonic() - stages.start:.0f} s")
    for name, why in stages.failed.items():
        print(f"FAILED {name}: {why}")
    print("\n| figure | target | measured |\n| --- | --- | --- |")  # docs/benchmarks.md's form
    for figure, target, value in summary(args.device, args.batch_size, rows, measured):
        print(f"| {figure} | {target} | {value} |")


if __name__ == "__main__":
    main()
