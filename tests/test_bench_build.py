"""bench/bench_build.py's verdict on two builds: alike, alike but for the format, or not."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import numpy as np
from test_build import as_format_3

from ngsim_graphs import layout

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
import bench_build  # noqa: E402


def verdict(old: Path, new: Path) -> str:
    differ = bench_build.differing_files(old, new)
    if not differ:
        return "alike"
    return "format" if bench_build.only_the_format_apart(old, new, differ) else "differ"


def test_builds_of_formats_3_and_4_are_alike_but_for_the_format(
    tiny_build: Path, tmp_path: Path
) -> None:
    older = tmp_path / "format-3"
    shutil.copytree(tiny_build, older)
    assert verdict(older, tiny_build) == "alike"
    as_format_3(older)
    assert verdict(older, tiny_build) == "format"
    # Anything else apart: a count of the manifest (re-sealed), then an array's value.
    manifest = json.loads(layout.manifest_path(older).read_text())
    manifest["counts"]["tracks"] += 1
    for key in ("files", "manifest_sha256"):
        del manifest[key]
    layout.write_manifest_json(older, manifest)
    assert verdict(older, tiny_build) == "differ"
    shutil.rmtree(older)
    shutil.copytree(tiny_build, older)
    as_format_3(older)
    entry = manifest["recordings"][0]
    path = layout.recording_arrays_dir(older, entry["location"], entry["period"]) / "pair_dist.npy"
    dist = np.load(path)
    dist[0] += 1.0
    np.save(path, dist)
    assert verdict(older, tiny_build) == "differ"
