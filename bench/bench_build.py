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
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import polars as pl

sys.path.insert(0, str(Path(__file__).parent))
from bench_ingest import ensure_input, parse_input_args  # noqa: E402
from memory import TreeMemory, process_peaks_gb  # noqa: E402

from ngsim_graphs import layout  # noqa: E402
from ngsim_graphs.budget import available_cores  # noqa: E402
from ngsim_graphs.config import BuildConfig  # noqa: E402
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


if __name__ == "__main__":
    main()
