"""Compare export-cslstm with CS-LSTM's own `preprocess_data.m` run under GNU Octave.

The script is not part of this project: pass the path of `preprocess_data.m` from your clone of
nachiket92/conv-social-pooling. This makes a small input of all six recordings from the
synthetic data (the first vehicles of each recording, those of at least 31 rows, where the script
would otherwise stop), writes it under the file names the script reads (`raw/us101-0750-0805.txt`
...), runs the script there with Octave (saving MAT v7, which scipy reads), runs the export on the
same files, and compares every value of `traj` and every cell of `tracks` in the three files.
Octave runs the script at about 100 rows/s, so the default input (about 3,000 rows) takes a minute
or two; this is not part of CI.

    python bench/compare_octave.py --script ~/conv-social-pooling/preprocess_data.m

Synthetic data: these are not NGSIM results.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from scipy.io import loadmat

sys.path.insert(0, str(Path(__file__).parent))
from bench_ingest import ensure_input  # noqa: E402

from ngsim_graphs.cslstm import DATASET_IDS  # noqa: E402
from ngsim_graphs.cslstm_export import FILE_NAMES, export_cslstm  # noqa: E402

# The script's input names, by dataset id (docs/cslstm.md).
SCRIPT_NAMES = {
    1: "us101-0750-0805.txt",
    2: "us101-0805-0820.txt",
    3: "us101-0820-0835.txt",
    4: "i80-1600-1615.txt",
    5: "i80-1700-1715.txt",
    6: "i80-1715-1730.txt",
}


def _repeated(line: str) -> str:
    """The line again at 2.5 ft further along: a repeated frame at another position."""
    fields = line.split()
    fields[5] = f"{float(fields[5]) + 2.5:.3f}"
    return " ".join(fields)


def small_input(synth_dir: Path, raw_dir: Path, vehicles: int, repeat_every: int) -> int:
    """The first `vehicles` vehicles (of >= 31 rows) of each synthetic recording, under the
    script's file names, every `repeat_every`-th row repeated at another position (0: none);
    returns the rows written."""
    raw_dir.mkdir(parents=True, exist_ok=True)
    written = 0
    for (location, period), dataset_id in DATASET_IDS.items():
        source = synth_dir / location / f"trajectories-{period}.txt"
        lines = [line for line in source.read_text().splitlines() if line.strip()]
        ids = np.array([int(line.split()[0]) for line in lines])
        counts = dict(zip(*np.unique(ids, return_counts=True), strict=True))
        chosen = sorted(v for v, n in counts.items() if n >= 31)[:vehicles]
        keep = np.isin(ids, chosen)
        out = []
        for line in (line for line, k in zip(lines, keep, strict=True) if k):
            out.append(line)
            if repeat_every and len(out) % repeat_every == 0:
                out.append(_repeated(line))
        (raw_dir / SCRIPT_NAMES[dataset_id]).write_text("\n".join(out) + "\n")
        written += len(out)
    return written


def compare(ours: Path, theirs: Path) -> list[str]:
    """Every difference between two exports, as lines; none when they are equal."""
    problems = []
    for name in FILE_NAMES.values():
        a, b = loadmat(ours / name), loadmat(theirs / name)
        if a["traj"].shape != b["traj"].shape:
            problems.append(f"{name}: traj {a['traj'].shape} here, {b['traj'].shape} there")
        elif not np.array_equal(a["traj"].astype(np.float32), b["traj"].astype(np.float32)):
            rows, columns = np.nonzero(a["traj"] != b["traj"])
            problems.append(
                f"{name}: traj differs in {len(rows):,} values, first at row {rows[0] + 1}, "
                f"column {columns[0] + 1}: {a['traj'][rows[0], columns[0]]} here, "
                f"{b['traj'][rows[0], columns[0]]} there"
            )
        ta, tb = a["tracks"], b["tracks"]
        if ta.shape != tb.shape:
            problems.append(f"{name}: tracks {ta.shape} here, {tb.shape} there")
            continue
        for index in np.ndindex(ta.shape):
            x, y = np.asarray(ta[index]), np.asarray(tb[index])
            if x.size == 0 and y.size == 0:
                continue
            if x.shape != y.shape or not np.array_equal(x, y.astype(x.dtype)):
                problems.append(f"{name}: tracks cell {tuple(i + 1 for i in index)} differs")
    return problems


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--script", type=Path, required=True, help="preprocess_data.m")
    parser.add_argument("--vehicles", type=int, default=6, help="vehicles per recording")
    parser.add_argument("--work-dir", type=Path, default=Path("bench/out/octave"))
    parser.add_argument(
        "--repeat-every", type=int, default=97, help="repeat every N-th row at +2.5 ft (0: none)"
    )
    parser.add_argument("--quirks", action="store_true", help="synthesize with frame gaps")
    parser.add_argument("--octave", default="octave")
    args = parser.parse_args()
    if shutil.which(args.octave) is None:
        sys.exit(
            f"error: {args.octave}: not found (install GNU Octave, e.g. apt-get install octave)"
        )
    synth_dir = args.work_dir.parent / f"raw-txt-r6-m1{'-quirks' if args.quirks else ''}"
    ensure_input(synth_dir, "txt", 6, 1.0, args.quirks)
    work = args.work_dir
    shutil.rmtree(work, ignore_errors=True)
    rows = small_input(synth_dir, work / "raw", args.vehicles, args.repeat_every)
    print(
        f"input      {rows:,} rows: {args.vehicles} vehicles of each of the six recordings, "
        f"every {args.repeat_every}th row repeated, quirks {'on' if args.quirks else 'off'}"
    )

    start = time.perf_counter()
    export_cslstm([work / "raw"], work / "ours")
    print(f"export     {time.perf_counter() - start:.2f} s")

    start = time.perf_counter()
    script = args.script.resolve()
    command = f"save_default_options('-v7'); source('{script}');"
    subprocess.run(
        [args.octave, "--no-gui", "--quiet", "--no-window-system", "--eval", command],
        cwd=work,
        check=True,
    )
    octave_s = time.perf_counter() - start
    (work / "octave").mkdir()
    for name in FILE_NAMES.values():
        saved = work / name if (work / name).exists() else work / Path(name).stem  # Octave: no .mat
        saved.rename(work / "octave" / name)
    print(f"octave     {octave_s:.1f} s ({rows / octave_s:,.0f} rows/s)")

    problems = compare(work / "ours", work / "octave")
    for line in problems[:20]:
        print(line)
    sizes = {name: loadmat(work / "ours" / name)["traj"].shape[0] for name in FILE_NAMES.values()}
    verdict = "EQUAL" if not problems else f"{len(problems)} DIFFERENCES"
    print(f"result     {verdict}: traj rows {sizes}, every value and every tracks cell compared")
    sys.exit(1 if problems else 0)


if __name__ == "__main__":
    main()
