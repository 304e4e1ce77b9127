"""synth's marker read back: which inputs synth wrote, and what `stats` and `show` say of a build
of them (a `"synthetic"` key, a red label at the top left of every picture)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from ngsim_cli.ngsim import app
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.pipeline import run_build
from ngsim_graphs.plotting import PLOT_NAMES
from ngsim_graphs.synth.marker import MARKER_NAME, SYNTHETIC_LABEL, written_by_synth

LABEL_ROWS = 40  # the top of a picture, where the label is drawn


def label_pixels(path: Path) -> int:
    """Pixels of the label's red (crimson, 220 20 60, and its antialiased shades) in the top rows
    of a PNG: none in a picture without the label (the scenes' red ego is further down)."""
    rgb = np.asarray(Image.open(path).convert("RGB"), dtype=np.int16)[:LABEL_ROWS]
    red, green, blue = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    return int(((red > 180) & (green < 110) & (blue > 40) & (blue < 130) & (red - blue > 90)).sum())


@pytest.fixture(scope="module")
def plain_build(tiny_build: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The tiny build's inputs copied without synth's marker, built alike: not synthetic."""
    root = tmp_path_factory.mktemp("plain")
    shutil.copytree(tiny_build.parent / "raw", root / "raw", ignore=shutil.ignore_patterns("*.md"))
    run_build([root / "raw"], root / "build", BuildConfig(d_sense_m=12.0, d_min_m=6.0))
    return root / "build"


def invoke(*args: object):  # noqa: ANN201
    return CliRunner(env={"COLUMNS": "200"}).invoke(app, [str(a) for a in args])


def test_a_file_is_synths_when_a_marker_beside_or_above_it_lists_it(tmp_path: Path) -> None:
    (tmp_path / "i-80").mkdir()
    for name in ("a.csv", "b.csv", "i-80/c.txt", "i-80/d.txt"):
        (tmp_path / name).write_text("rows\n")
    (tmp_path / MARKER_NAME).write_text("# Synthetic data\n\nFiles:\n\n- a.csv\n- i-80/c.txt\n")
    assert written_by_synth(tmp_path / "a.csv") and written_by_synth(tmp_path / "i-80" / "c.txt")
    assert not written_by_synth(tmp_path / "b.csv")  # beside synth's files, not listed
    assert not written_by_synth(tmp_path / "i-80" / "d.txt")
    (tmp_path / MARKER_NAME).unlink()
    assert not written_by_synth(tmp_path / "a.csv")


def test_stats_json_says_whether_the_build_is_synthetic(
    tiny_build: Path, plain_build: Path
) -> None:
    for build, synthetic in ((tiny_build, True), (plain_build, False)):
        result = invoke("stats", build, "--json", "--degree-graphs", "5")
        assert result.exit_code == 0, result.output
        assert json.loads(result.stdout)["synthetic"] is synthetic
    table = invoke("stats", tiny_build, "--degree-graphs", "5")
    assert table.stdout.startswith(f"{tiny_build}: {SYNTHETIC_LABEL}.\n")
    assert SYNTHETIC_LABEL not in invoke("stats", plain_build, "--degree-graphs", "5").stdout


def test_stats_plots_of_a_synthetic_build_carry_the_label(
    tiny_build: Path, plain_build: Path, tmp_path: Path
) -> None:
    for build, synthetic in ((tiny_build, True), (plain_build, False)):
        folder = tmp_path / build.parent.name
        result = invoke("stats", build, "--plots", folder, "--degree-graphs", "5")
        assert result.exit_code == 0, result.output
        for name in PLOT_NAMES:
            pixels = label_pixels(folder / f"{name}.png")
            assert pixels > 200 if synthetic else pixels == 0, (name, pixels)


def test_show_of_a_synthetic_build_carries_the_label(
    tiny_build: Path, plain_build: Path, tmp_path: Path
) -> None:
    synthetic = invoke("show", tiny_build, "--sample", "0:2", "--out", tmp_path / "synth.png")
    assert synthetic.exit_code == 0, synthetic.output
    assert synthetic.stdout.rstrip().endswith(f"; {SYNTHETIC_LABEL}")
    plain = invoke("show", plain_build, "--sample", "0:2", "--out", tmp_path / "plain.png")
    assert plain.exit_code == 0, plain.output
    assert SYNTHETIC_LABEL not in plain.stdout
    assert label_pixels(tmp_path / "synth.png") > 200
    assert label_pixels(tmp_path / "plain.png") == 0
