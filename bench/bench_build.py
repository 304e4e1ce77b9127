"""Benchmark: the whole `ngsim-graphs build` at full NGSIM scale, stage by stage.

Generates (or reuses) the synthetic input with `ngsim-graphs synth` in a child process, then runs
`run_build` here and prints wall seconds per stage, samples and edges per second, the output's
size on disk and the peak resident memory of all the build's processes together (bench/memory.py).
Synthetic data: these are not NGSIM results.

    python bench/bench_build.py --format txt            # six recordings of 15 minutes
    python bench/bench_build.py --format txt --recordings 2   # memory must not grow with this
    taskset -c 0,1 python bench/bench_build.py --format txt   # two cores (two jobs by default)
    python bench/bench_build.py --format txt --jobs 1   # one process
    python bench/bench_build.py --format txt --protocol cs-lstm   # a sample per CS-LSTM row
    python bench/bench_build.py --format txt --largest 2   # the 2 largest of the 6 recordings
    python bench/bench_build.py --format txt --against none   # this tree only

Last, it builds the same input with the code of `--against REV` (default 66e4b70, main before
issue 52's work) and with this tree, alternating, `--rounds` times, each build in a fresh
process (`build_once.py`, the checkout on PYTHONPATH; REV checked out once as a git worktree
under the work dir), and prints the medians of both and of their ratio (timings on a shared
machine are comparable only side by side), and whether the last two builds are byte for byte
alike (against a build of format 3, whose pairs are also in proximity tables: alike but for
those and their records).
"""

from __future__ import annotations

import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

import polars as pl

sys.path.insert(0, str(Path(__file__).parent))
from bench_ingest import ensure_input, parse_input_args  # noqa: E402
from memory import TreeMemory, process_peaks_gb  # noqa: E402

from ngsim_graphs import integrity, layout  # noqa: E402
from ngsim_graphs.budget import available_cores  # noqa: E402
from ngsim_graphs.config import BuildConfig  # noqa: E402
from ngsim_graphs.integrity import file_sha256  # noqa: E402
from ngsim_graphs.pipeline import run_build  # noqa: E402
from ngsim_graphs.schema import Protocol  # noqa: E402


def folder_bytes(folder: Path) -> dict[str, int]:
    """Bytes on disk per top-level entry of a build."""
    sizes: dict[str, int] = {}
    for path in folder.rglob("*"):
        if path.is_file():
            top = path.relative_to(folder).parts[0]
            sizes[top] = sizes.get(top, 0) + path.stat().st_size
    return sizes


def largest_files(raw_dir: Path, count: int, fmt: str) -> list[Path]:
    """The `count` largest recording files of a synthetic txt or csv input (one per recording)."""
    if fmt == "portal":
        raise SystemExit("--largest: the portal format holds every recording in one file")
    files = sorted(raw_dir.rglob(f"*.{fmt}"), key=lambda path: path.stat().st_size, reverse=True)
    if not 1 <= count <= len(files):
        raise SystemExit(f"--largest {count}: {raw_dir} has {len(files)} recording files")
    return files[:count]


ROOT = Path(__file__).resolve().parents[1]


def checkout(revision: str, work_dir: Path) -> Path:
    """A checkout of `revision` (a git worktree under `work_dir`, made once)."""
    commit = subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "--short=7", revision],
        check=True, capture_output=True, text=True,
    ).stdout.strip()  # fmt: skip
    folder = (work_dir / f"wt-{commit}").resolve()
    if not (folder / "ngsim_graphs").is_dir():
        subprocess.run(
            ["git", "-C", str(ROOT), "worktree", "add", "--detach", str(folder), commit],
            check=True, capture_output=True,
        )  # fmt: skip
    return folder


def timed_build(code: Path, inputs: list[Path], out: Path, jobs: int, protocol: str) -> dict:
    """One build by the checkout at `code` in a process of its own: its wall seconds and stages
    (build_once.py) and the peak memory of its processes summed."""
    command = [sys.executable, str(Path(__file__).with_name("build_once.py")), *map(str, inputs)]
    command += [str(out), "--jobs", str(jobs), "--protocol", protocol]
    environment = dict(os.environ, PYTHONPATH=str(code))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    build = subprocess.Popen(
        command, env=environment, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    with TreeMemory(build.pid) as memory:  # the build's processes, not this one's
        stdout, stderr = build.communicate()
    after = resource.getrusage(resource.RUSAGE_CHILDREN)  # the build's processes, all ended
    cpu_s = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    if build.returncode:
        raise SystemExit(f"the build of {code} failed:\n{stderr[-3000:]}")
    figures = json.loads(stdout.strip().splitlines()[-1])
    return figures | {"peak_gb": memory.peak_bytes / 1024**3, "cpu_s": cpu_s}


def differing_files(first: Path, second: Path) -> list[str]:
    """The files of two builds whose bytes differ or that only one has, build.log aside (each
    build's own times)."""

    def digests(root: Path) -> dict[str, str]:
        files = (p for p in root.rglob("*") if p.is_file() and p != layout.build_log_path(root))
        return {str(p.relative_to(root)): file_sha256(p) for p in files}

    a, b = digests(first), digests(second)
    return sorted(name for name in a.keys() | b.keys() if a.get(name) != b.get(name))


def only_the_format_apart(first: Path, second: Path, differ: list[str]) -> bool:
    """Whether two builds that differ in `differ` differ only as formats 3 and 4 do: one is of
    format 3 and one of 4, and the files apart are the format-3 build's proximity tables (its
    pairs again) and the manifests, which differ only in their format version and the records
    of those tables."""
    manifests = {
        root: json.loads((root / layout.MANIFEST_NAME).read_text()) for root in (first, second)
    }
    if sorted(m.get("format_version") for m in manifests.values()) != [3, 4]:
        return False
    older, newer = sorted((first, second), key=lambda root: manifests[root]["format_version"])
    tables = layout.PROXIMITY_DIR + "/"
    if (newer / layout.PROXIMITY_DIR).exists():
        return False
    for name in differ:
        if name == layout.MANIFEST_NAME:
            continue
        if not name.startswith(tables) or not (older / name).is_file():
            return False

    def body(root: Path) -> dict:
        content = dict(manifests[root])
        files = content.pop(integrity.FILES_KEY)
        for key in ("format_version", integrity.CHECKSUM_KEY):
            content.pop(key)
        kept = {k: v for k, v in files.items() if not k.startswith(tables)}
        return content | {integrity.FILES_KEY: kept}

    return body(first) == body(second)


def side_by_side(args, inputs: list[Path], name: str, jobs: int) -> None:
    """Builds of `inputs` by `--against` and by this tree, alternating, `--rounds` times."""
    codes = {args.against: checkout(args.against, args.work_dir), "this tree": ROOT}
    runs: dict[str, list[dict]] = {label: [] for label in codes}
    for _ in range(args.rounds):
        for label, code in codes.items():
            out = args.work_dir / f"{name}-{code.name}"
            runs[label].append(timed_build(code, inputs, out, jobs, args.protocol))
    outs = [args.work_dir / f"{name}-{code.name}" for code in codes.values()]
    base, this = runs[args.against], runs["this tree"]
    ratios = [b["wall_s"] / t["wall_s"] for b, t in zip(base, this, strict=True)]
    cpu_ratios = [b["cpu_s"] / t["cpu_s"] for b, t in zip(base, this, strict=True)]
    load = os.getloadavg()
    print(
        f"side by side       {args.rounds} rounds, alternating, {jobs} jobs (load now {load[0]:.1f})"
    )
    for label, figures in runs.items():
        walls = ", ".join(f"{f['wall_s']:.1f}" for f in figures)
        wall = statistics.median(f["wall_s"] for f in figures)
        peak = statistics.median(f["peak_gb"] for f in figures)
        cpu = statistics.median(f["cpu_s"] for f in figures)
        print(f"  {label:<16} wall {wall:6.1f} s (median of {walls}), peak {peak:.2f} GB")
        print(f"  {'':<16} CPU {cpu:6.1f} s (user + system, every process of the build)")
        stages = {
            k: statistics.median(f["stages"].get(k, 0.0) for f in figures)
            for k in figures[0]["stages"]
        }
        print("  " + " " * 17 + ", ".join(f"{k} {v:.1f} s" for k, v in stages.items()))
    for what, values in (("wall", ratios), ("CPU", cpu_ratios)):
        print(
            f"  {args.against} / this tree, {what}: {statistics.median(values):.2f} times as "
            f"long (median; {min(values):.2f} to {max(values):.2f})"
        )
    differ = differing_files(*outs)
    if not differ:
        verdict = "byte for byte alike"
    elif only_the_format_apart(*outs, differ):
        verdict = "byte for byte alike but for format 3's proximity tables and their records"
    else:
        verdict = "DIFFER"
    shown = f": {', '.join(differ[:5])}" if differ and verdict == "DIFFER" else ""
    print(f"  the two builds: {verdict} (sha256 of every file, build.log aside){shown}")


def main() -> None:
    args, tag, raw_dir = parse_input_args(__doc__, "txt", largest=True)
    synth_s = ensure_input(raw_dir, args.format, args.recordings, args.minutes, args.quirks)

    inputs, name = [raw_dir], f"graphs-{tag}"
    if args.largest is not None:
        inputs, name = (
            largest_files(raw_dir, args.largest, args.format),
            f"{name}-largest{args.largest}",
        )
    if args.protocol != "aigem":
        name += f"-{args.protocol}"

    marks: list[tuple[str, int, float]] = []
    jobs = args.jobs or available_cores()
    start = time.perf_counter()
    with TreeMemory() as memory:
        result = run_build(
            inputs,
            args.work_dir / name,
            BuildConfig(protocol=Protocol(args.protocol)),
            overwrite=True,
            progress=lambda what, done, _total: marks.append((what, done, time.perf_counter())),
            jobs=jobs,
        )
    end = time.perf_counter()
    own_gb, child_gb = process_peaks_gb()

    stages: dict[str, float] = {}
    stage_peaks: dict[str, int] = {}
    for (what, _, at), (_, _, until) in zip(marks, [*marks[1:], ("end", 0, end)], strict=True):
        stage = "reading + staging" if what.startswith("reading") else what.split(" ")[0]
        stages[stage] = stages.get(stage, 0.0) + until - at
        stage_peaks[stage] = max(stage_peaks.get(stage, 0), memory.peak_between(at, until))
    samples = pl.concat(
        [
            pl.read_parquet(layout.samples_path(result.out_dir, split))
            for split in ("train", "val", "test")
        ]
    )
    wall_s = end - start
    n_spatial = int(samples["n_spatial_edges"].cast(pl.Int64).sum())
    n_temporal = int(samples["n_temporal_edges"].cast(pl.Int64).sum())
    sizes = folder_bytes(result.out_dir)
    counts = result.manifest.counts
    print(
        f"input              {tag}: {counts.rows_read:,} rows, {len(result.recordings)} recordings"
    )
    print(
        f"jobs               {jobs} (of {available_cores()} usable cores), {args.protocol} protocol"
    )
    for stage, seconds in stages.items():
        peak = stage_peaks[stage]  # 0: shorter than one sample
        shown = f"{peak / 1024**3:.2f} GB" if peak else "-"
        print(f"  {stage:<17}{seconds:7.1f} s   peak {shown}")
    print(f"wall               {wall_s:.1f} s")
    print(f"samples            {samples.height:,} ({dict(result.manifest.splits)})")
    print(
        f"graph edges        {n_spatial:,} spatial, {n_temporal:,} temporal (counted, not stored)"
    )
    print(f"samples per second {samples.height / wall_s:,.0f}")
    print(f"edges per second   {(n_spatial + n_temporal) / wall_s:,.0f}")
    print(
        f"proximity edges    {counts.proximity_edges:,} stored (pairs within d_min, once per step)"
    )
    print(
        "output on disk     "
        + ", ".join(f"{k} {v / 1e6:.0f} MB" for k, v in sorted(sizes.items()))
        + f"; total {sum(sizes.values()) / 1e9:.2f} GB"
    )
    print(
        f"peak memory        {memory.peak_bytes / 1024**3:.2f} GB (all processes, summed; "
        f"max RSS {own_gb:.2f} GB of this one, {child_gb:.2f} GB of the largest worker"
        + (", or of synth, which made the input in this run" if synth_s else "")
        + ")"
    )
    if args.against != "none":
        side_by_side(args, inputs, name, jobs)


if __name__ == "__main__":
    main()
