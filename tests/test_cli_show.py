"""`ngsim-graphs show` through typer's CliRunner: the PNG it writes, what it says it drew, and one
error line with a non-zero exit (2: a bad option, 1: a bad build or output) for what it refuses."""

from __future__ import annotations

import json
from pathlib import Path

import polars as pl
import pytest
from conftest import straight_track, write_txt
from PIL import Image
from typer.testing import CliRunner, Result

from ngsim_cli.ngsim import app
from ngsim_graphs.build import open_build
from ngsim_graphs.scenes import DPI, GRAPH_PANEL_IN, TARGET_PANEL_IN
from ngsim_graphs.synth.marker import SYNTHETIC_LABEL

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def invoke(*args: object, columns: int = 200) -> Result:
    return CliRunner(env={"COLUMNS": str(columns)}).invoke(app, [str(a) for a in args])


def error_line(result: Result, code: int) -> str:
    assert result.exit_code == code, result.output
    assert result.stdout == ""
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    return lines[0]


def assert_png(path: Path, min_bytes: int = 20_000) -> tuple[int, int]:
    data = path.read_bytes()
    assert data.startswith(PNG_SIGNATURE) and len(data) > min_bytes
    return Image.open(path).size


def _egos(samples: pl.DataFrame) -> list[tuple[str, str, int]]:
    return list(samples.select("location", "period", "ego_track_id").iter_rows())


def test_show_three_samples_one_ego_each(tiny_build: Path, tmp_path: Path) -> None:
    """START:END draws END-START distinct egos, the first sample of each from START on: the
    tiny build's val samples come two by two per ego, so 0:3 draws samples 0, 2 and 4."""
    out = tmp_path / "three.png"
    result = invoke("show", tiny_build, "--split", "val", "--sample", "0:3", "--out", out)
    assert result.exit_code == 0, result.output
    all_samples = open_build(tiny_build).samples("val")
    assert len(set(_egos(all_samples.head(4)))) == 2  # two windows of each of two egos
    samples = all_samples.filter(pl.col("sample_id").is_in([0, 2, 4]))
    assert len(set(_egos(samples))) == 3
    nodes, targets = samples["n_nodes"].sum(), samples["n_targets"].sum()
    assert result.stdout == (
        f"wrote {out}: val samples 0, 2, 4 (one per ego) of {tiny_build} ({nodes:,} nodes, "
        f"{targets:,} targets); {SYNTHETIC_LABEL}\n"
    )
    assert assert_png(out)[0] == 2 * GRAPH_PANEL_IN * DPI  # two panels a row, by default
    out.unlink()
    assert (
        invoke(
            "show", tiny_build, "--split", "val", "--sample", "0:3", "--out", out, "--columns", "3"
        ).exit_code
        == 0
    )
    assert assert_png(out)[0] == 3 * GRAPH_PANEL_IN * DPI


def test_show_every_window(tiny_build: Path, tmp_path: Path) -> None:
    out = tmp_path / "three.png"
    args = ("show", tiny_build, "--split", "val", "--sample", "0:3", "--every-window")
    result = invoke(*args, "--out", out)
    assert result.exit_code == 0, result.output
    samples = open_build(tiny_build).samples("val").head(3)
    nodes, targets = samples["n_nodes"].sum(), samples["n_targets"].sum()
    assert result.stdout == (
        f"wrote {out}: val samples 0..2 of {tiny_build} ({nodes:,} nodes, {targets:,} targets); "
        f"{SYNTHETIC_LABEL}\n"
    )


def test_default_name_and_overwrite(
    tiny_build: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    result = invoke("show", tiny_build, "--sample", "2")
    out = tmp_path / "show-test-2.png"
    assert result.exit_code == 0 and result.stdout.startswith(f"wrote {out}: test sample 2 of ")
    assert_png(out)
    out.write_text("mine\n")  # a file that is not ours now
    line = error_line(invoke("show", tiny_build, "--sample", "2"), 1)
    assert line == f"error: {out}: exists; pass --overwrite to replace it"
    assert out.read_text() == "mine\n"
    assert invoke("show", tiny_build, "--sample", "2", "--overwrite").exit_code == 0
    assert_png(out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["show-test-2.png"]  # no partial file


def test_the_default_name_says_which_samples_it_holds(
    tiny_build: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """0:3 draws one sample per ego, 0, 2 and 4 of the val split (two windows per ego): named
    so, not 0-2; with --every-window, samples 0..2 are drawn and named 0-2."""
    monkeypatch.chdir(tmp_path)
    result = invoke("show", tiny_build, "--split", "val", "--sample", "0:3")
    out = tmp_path / "show-val-egos-0-to-4.png"
    assert result.stdout.startswith(f"wrote {out}: val samples 0, 2, 4 (one per ego) of ")
    result = invoke("show", tiny_build, "--split", "val", "--sample", "0:3", "--every-window")
    assert result.stdout.startswith(f"wrote {tmp_path / 'show-val-0-2.png'}: val samples 0..2 ")
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "show-val-0-2.png",
        "show-val-egos-0-to-4.png",
    ]


@pytest.mark.parametrize(
    ("spec", "fragment"),
    [
        ("5:2", "START:END needs 0 <= START < END"),
        ("3:3", "START:END needs 0 <= START < END"),
        ("x", "give N or START:END"),
        ("1:", "give N or START:END"),
        ("-1", "START:END needs 0 <= START < END"),
        ("0:65", "at most 64 samples"),
        ("100:110", "the val split has samples 0..{last}"),
    ],
)
def test_bad_sample(tiny_build: Path, tmp_path: Path, spec: str, fragment: str) -> None:
    out = tmp_path / "x.png"
    val = json.loads((tiny_build / "manifest.json").read_text())["splits"]["val"]
    assert 2 < val < 100
    fragment = fragment.format(last=val - 1)
    result = invoke("show", tiny_build, "--split", "val", "--sample", spec, "--out", out)
    line = error_line(result, 2)
    assert f"--sample {spec!r}" in line and fragment in line
    assert not out.exists()


def test_empty_split(tmp_path: Path) -> None:
    """Two vehicles of 41 grid steps: one train sample, one val sample, no test sample."""
    rows = straight_track(1, range(10, 92), x_ft=6.0, lane_id=1)
    rows += straight_track(2, range(10, 92), x_ft=18.0, speed_fps=40.0)
    build = tmp_path / "build"
    assert invoke("build", write_txt(tmp_path / "a.txt", rows), "--out", build).exit_code == 0
    line = error_line(invoke("show", build, "--out", tmp_path / "x.png"), 1)
    assert line == f"error: {build}: its test split is empty: nothing to draw"
    assert invoke("show", build, "--split", "val", "--out", tmp_path / "x.png").exit_code == 0


def test_not_a_build(tmp_path: Path) -> None:
    line = error_line(invoke("show", tmp_path, "--out", tmp_path / "x.png"), 1)
    assert str(tmp_path) in line and "not a build" in line


def test_show_with_a_run(tiny_build: Path, tiny_run: Path, tmp_path: Path) -> None:
    out = tmp_path / "run.png"
    result = invoke(
        "show", tiny_build, "--split", "val", "--sample", "0:2", "--run", tiny_run, "--out", out
    )
    assert result.exit_code == 0, result.output
    assert result.stdout.rstrip().endswith(
        "; each panel follows its median target, beside AiGem's and constant velocity's "
        f"predictions of {tiny_run}; {SYNTHETIC_LABEL}"
    )
    assert assert_png(out)[0] == 2 * TARGET_PANEL_IN * DPI


def test_show_with_a_run_of_another_build(
    two_recording_build: Path, tiny_run: Path, tmp_path: Path
) -> None:
    result = invoke(
        "show",
        two_recording_build,
        "--split",
        "val",
        "--run",
        tiny_run,
        "--out",
        tmp_path / "x.png",
    )
    line = error_line(result, 1)
    assert "not the build that run" in line and "made on its own build only" in line
    assert not (tmp_path / "x.png").exists()


def test_help_fits_80_columns() -> None:
    result = invoke("show", "--help", columns=80)
    assert result.exit_code == 0
    assert max(len(line) for line in result.stdout.splitlines()) <= 80
    for option in ("--split", "--sample", "--out", "--run", "--overwrite", "--columns"):
        assert option in result.stdout
