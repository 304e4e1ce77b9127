"""Benchmark: raw NGSIM-format files to the tracks table, at full NGSIM scale.

Generates (or reuses) the six-recording, 15-minute synthetic input with `ngsim-graphs synth` in
a child process, then times `run_build` in this process and prints rows, wall seconds, rows per
second and peak resident memory. The input is synthetic: these are not NGSIM results.

An input is reused only when this checkout's generator made it: beside it, `raw-TAG.generator`
holds the sha256 of the generator's sources (ngsim_graphs/synth) that made it; an input of other
sources, or of none recorded, is made again (synth replaces a folder of its own files).

    python bench/bench_ingest.py --format portal --quirks
"""

from __future__ import annotations

import argparse
import hashlib
import resource
import subprocess
import sys
import time
from pathlib import Path

from ngsim_graphs.config import BuildConfig
from ngsim_graphs.pipeline import run_build


def generator_digest() -> str:
    """sha256 over the synthetic generator's source files (their names and bytes)."""
    import ngsim_graphs.synth

    folder = Path(ngsim_graphs.synth.__file__).parent
    digest = hashlib.sha256()
    for path in sorted(folder.rglob("*.py")):
        digest.update(path.relative_to(folder).as_posix().encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()


def ensure_input(
    raw_dir: Path, raw_format: str, recordings: int, minutes: float, quirks: bool
) -> float:
    """Synthesize the input unless this checkout's generator made it already (the digest beside
    it); returns the seconds it took (0 if reused)."""
    stamp, generator = raw_dir.with_name(f"{raw_dir.name}.generator"), generator_digest()
    if raw_dir.is_dir() and any(raw_dir.rglob("*.*")):
        if stamp.is_file() and stamp.read_text().strip() == generator:
            return 0.0
        print(f"{raw_dir}: not made by this checkout's generator; made again", file=sys.stderr)
    command = [
        sys.executable,
        "-m",
        "ngsim_cli.ngsim",
        "synth",
        str(raw_dir),
        "--format",
        raw_format,
        "--recordings",
        str(recordings),
        "--minutes",
        str(minutes),
        "--seed",
        "0",
    ] + (["--quirks"] if quirks else [])
    start = time.perf_counter()
    stamp.unlink(missing_ok=True)  # no stamp while the input is being made
    subprocess.run(command, check=True)
    stamp.write_text(generator + "\n")
    return time.perf_counter() - start


def parse_input_args(
    description: str, default_format: str, largest: bool = False
) -> tuple[argparse.Namespace, str, Path]:
    """The options that choose the synthetic input (and `--largest`, where asked); returns (args,
    tag, raw folder)."""
    parser = argparse.ArgumentParser(
        description=description, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--format", default=default_format, choices=["portal", "csv", "txt"])
    parser.add_argument("--recordings", type=int, default=6)
    parser.add_argument("--minutes", type=float, default=15.0)
    parser.add_argument("--quirks", action="store_true")
    parser.add_argument("--work-dir", type=Path, default=Path("bench/out"))
    parser.add_argument(
        "--jobs", type=int, default=None, help="build processes (default: one per usable core)"
    )
    parser.add_argument("--protocol", default="aigem", choices=["aigem", "cs-lstm"])
    if largest:  # bench_build.py's own options
        parser.add_argument(
            "--against",
            default="66e4b70",
            help="a revision built beside this tree, alternating (none: no other)",
        )
        parser.add_argument("--rounds", type=int, default=3, help="side-by-side rounds")
        parser.add_argument(
            "--largest",
            type=int,
            default=None,
            help="build only the N largest recordings' files (txt or csv): peak memory is set by "
            "the largest recordings and the jobs, not by how many recordings there are",
        )
    args = parser.parse_args()
    tag = f"{args.format}-r{args.recordings}-m{args.minutes:g}{'-quirks' if args.quirks else ''}"
    return args, tag, args.work_dir / f"raw-{tag}"


def main() -> None:
    args, tag, raw_dir = parse_input_args(__doc__, "portal")
    synth_s = ensure_input(raw_dir, args.format, args.recordings, args.minutes, args.quirks)
    input_bytes = sum(p.stat().st_size for p in raw_dir.rglob("*") if p.is_file())

    start = time.perf_counter()
    result = run_build([raw_dir], args.work_dir / f"build-{tag}", BuildConfig(), overwrite=True)
    wall_s = time.perf_counter() - start
    peak_gb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2  # ru_maxrss is KiB

    counts = result.manifest.counts
    print(f"input            {tag}: {input_bytes / 1e9:.2f} GB (synth {synth_s:.1f} s, 0 = reused)")
    print(f"rows read        {counts.rows_read:,}")
    print(f"tracks rows      {counts.grid_rows:,} on the 0.2 s grid, {counts.tracks:,} tracks")
    print(f"wall             {wall_s:.1f} s")
    print(f"rows per second  {counts.rows_read / wall_s:,.0f}")
    print(f"peak memory      {peak_gb:.2f} GB (max RSS of this process)")


if __name__ == "__main__":
    main()
