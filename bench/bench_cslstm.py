"""Benchmark: `ngsim-graphs export-cslstm` at full NGSIM scale, beside CS-LSTM's own script.

Generates (or reuses) the six-recording synthetic input with `ngsim-graphs synth`, then runs the
export here and prints wall seconds per stage, rows per second, the files' sizes and the peak
resident memory, beside what `preprocess_data.m` takes under GNU Octave: about 100-120 rows/s
(measured on 214,267 real US-101 rows: 34 minutes). Run it on 2 cores as the target says:

    POLARS_MAX_THREADS=2 taskset -c 0,1 python bench/bench_cslstm.py    # target: <= 120 s, 4 GB

Synthetic data: these are not NGSIM results.
"""

from __future__ import annotations

import resource
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from bench_ingest import ensure_input, parse_input_args  # noqa: E402

from ngsim_graphs.cslstm_export import FILE_NAMES, export_cslstm  # noqa: E402

SCRIPT_ROWS_PER_S = (100, 120)  # preprocess_data.m under GNU Octave


def main() -> None:
    args, tag, raw_dir = parse_input_args(__doc__, "txt")
    ensure_input(raw_dir, args.format, args.recordings, args.minutes, args.quirks)
    out = args.work_dir / f"cslstm-{tag}"
    marks: list[tuple[str, float]] = []
    start = time.perf_counter()
    result = export_cslstm(
        [raw_dir],
        out,
        allow_partial=args.recordings < 6,
        overwrite=True,
        progress=lambda what, _done, _total: marks.append((what, time.perf_counter())),
    )
    end = time.perf_counter()
    peak_gb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2  # KiB -> GiB
    stages: dict[str, float] = {}
    for (what, at), (_, until) in zip(marks, [*marks[1:], ("end", end)], strict=True):
        stage = what.split(" ")[0] if not what.startswith("dataset") else "maneuvers + grid"
        stages[stage] = stages.get(stage, 0.0) + until - at
    rows = sum(d.rows for d in result.datasets)
    wall_s = end - start
    print(f"input              {tag}: {rows:,} rows, {len(result.datasets)} recordings")
    for stage, seconds in stages.items():
        print(f"  {stage:<17}{seconds:7.1f} s")
    print(f"wall               {wall_s:.1f} s")
    print(f"rows per second    {rows / wall_s:,.0f}")
    low, high = SCRIPT_ROWS_PER_S
    print(
        f"the script         {low}-{high} rows/s under Octave: {rows / high / 3600:.1f}-"
        f"{rows / low / 3600:.1f} h for these rows ({rows / wall_s / high:,.0f}-"
        f"{rows / wall_s / low:,.0f} times slower)"
    )
    for name, count in result.rows.items():
        size = (out / FILE_NAMES[name]).stat().st_size
        print(f"{FILE_NAMES[name]:<19}traj {count:,} x 47, {size / 2**20:,.0f} MiB")
    print(f"peak memory        {peak_gb:.2f} GiB (resident)")


if __name__ == "__main__":
    main()
