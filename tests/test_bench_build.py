"""bench/bench_build.py's verdict on two builds: alike, alike but for the format, or not."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import numpy as np
from test_build import as_format_3, reseal

from ngsim_graphs import layout

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
import bench_build  # noqa: E402


def verdict(old: Path, new: Path) -> str:
    differ = bench_build.differing_files(old, new)
    if not differ:
        return "alike"
    return "format" if bench_build.only_the_format_apart(old, new, differ) else "differ"


def copies(tiny_build: Path, tmp_path: Path) -> tuple[Path, Path]:
    """(a copy made a build of format 3, a copy as it is) of the tiny build."""
    older, newer = tmp_path / "format-3", tmp_path / "format-4"
    for copy in (older, newer):
        shutil.rmtree(copy, ignore_errors=True)
        shutil.copytree(tiny_build, copy)
    assert verdict(older, newer) == "alike"
    as_format_3(older)
    return older, newer


def test_builds_of_formats_3_and_4_are_alike_but_for_the_format(
    tiny_build: Path, tmp_path: Path
) -> None:
    older, newer = copies(tiny_build, tmp_path)
    assert verdict(older, newer) == verdict(newer, older) == "format"


def test_anything_else_apart_is_a_difference(tiny_build: Path, tmp_path: Path) -> None:
    """A count of the manifest; an array's value; a proximity table in the format-4 build
    too; two builds whose versions are not 3 and 4."""
    older, newer = copies(tiny_build, tmp_path)
    counts = json.loads(layout.manifest_path(older).read_text())["counts"]
    reseal(older, counts={**counts, "tracks": counts["tracks"] + 1})
    assert verdict(older, newer) == "differ"

    older, newer = copies(tiny_build, tmp_path)
    entry = json.loads(layout.manifest_path(older).read_text())["recordings"][0]
    path = layout.recording_arrays_dir(older, entry["location"], entry["period"]) / "pair_dist.npy"
    dist = np.load(path)
    dist[0] += 1.0
    np.save(path, dist)
    reseal(older)
    assert verdict(older, newer) == "differ"

    older, newer = copies(tiny_build, tmp_path)
    table = layout.proximity_path(newer, entry["location"], entry["period"])
    table.parent.mkdir()
    shutil.copy(layout.proximity_path(older, entry["location"], entry["period"]), table)
    reseal(newer)
    assert verdict(older, newer) == "differ"

    older, newer = copies(tiny_build, tmp_path)
    reseal(newer, format_version=5)
    assert verdict(older, newer) == "differ"
