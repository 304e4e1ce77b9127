"""One `run_build` of whichever ngsim_graphs is first on the path, timed stage by stage.

`bench_build.py --against REV` runs this file in a fresh process per build, with PYTHONPATH set to
a checkout of REV or of this tree, so that two checkouts are timed alike on one input: it uses
only what every checkout since ebdaa5f has (`run_build`, `BuildConfig(protocol=...)`, the
progress callback). Prints one JSON line on stdout: wall seconds, seconds per stage, the checkout's
ngsim_graphs folder.

    PYTHONPATH=CHECKOUT python bench/build_once.py RAW... OUT_DIR [--jobs N] [--protocol P]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import ngsim_graphs
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.pipeline import run_build
from ngsim_graphs.schema import Protocol


def stage_seconds(marks: list[tuple[str, float]], end: float) -> dict[str, float]:
    """Seconds per stage (reading, cleaning, building, writing) from the progress calls' times."""
    stages: dict[str, float] = {}
    for (what, at), (_, until) in zip(marks, [*marks[1:], ("end", end)], strict=True):
        stage = "reading" if what.startswith(("reading", "unpacking")) else what.split(" ")[0]
        stages[stage] = stages.get(stage, 0.0) + until - at
    return stages


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("paths", type=Path, nargs="+", help="the inputs, then the output folder")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--protocol", default="aigem")
    args = parser.parse_args()
    marks: list[tuple[str, float]] = []
    start = time.perf_counter()
    run_build(
        args.paths[:-1],
        args.paths[-1],
        BuildConfig(protocol=Protocol(args.protocol)),
        overwrite=True,
        progress=lambda what, _done, _total: marks.append((what, time.perf_counter())),
        jobs=args.jobs,
    )
    end = time.perf_counter()
    print(
        json.dumps(
            {
                "wall_s": end - start,
                "stages": stage_seconds(marks, end),
                "code": str(Path(ngsim_graphs.__file__).parent.parent),
            }
        )
    )


if __name__ == "__main__":
    main()
