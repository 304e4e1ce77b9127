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
from ngsim_graphs import integrity
from ngsim_graphs.config import BuildConfig, SynthConfig
from ngsim_graphs.pipeline import run_build
from ngsim_graphs.plotting import PLOT_NAMES
from ngsim_graphs.schema import RawFormat
from ngsim_graphs.synth.formats import write_synthetic
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


FAST_BUILD = ("--d-sense-m", "12", "--d-min-m", "6", "--stride-s", "2")


def test_a_build_is_synthetic_by_its_manifest_wherever_its_inputs_go(tmp_path: Path) -> None:
    """Told when the build reads its inputs and recorded: moving the raw files (or losing
    synth's marker) afterwards does not make a build of simulated data read as real."""
    raw = tmp_path / "raw"
    (path,) = write_synthetic(raw, SynthConfig(RawFormat.PORTAL, recordings=1, minutes=0.3))
    build = tmp_path / "build"
    assert invoke("build", raw, "--out", build, *FAST_BUILD).exit_code == 0
    manifest = json.loads((build / "manifest.json").read_text())
    assert (manifest["synthetic"], manifest["synthetic_inputs"]) == (True, [str(path)])
    raw.rename(tmp_path / "moved")
    document = json.loads(invoke("stats", build, "--json", "--degree-graphs", "5").stdout)
    assert (document["synthetic"], document["synthetic_inputs"]) == (True, [str(path)])
    shown = invoke("show", build, "--sample", "0:2", "--out", tmp_path / "scene.png")
    assert shown.exit_code == 0, shown.output
    assert shown.stdout.rstrip().endswith(f"; {SYNTHETIC_LABEL}")
    assert label_pixels(tmp_path / "scene.png") > 200


@pytest.mark.slow
def test_a_build_of_synthetic_and_other_inputs_names_both(tmp_path: Path) -> None:
    raw = tmp_path / "raw"
    ours, theirs = write_synthetic(raw, SynthConfig(RawFormat.CSV, recordings=2, minutes=0.3))
    measured = tmp_path / "measured" / theirs.name  # the same rows, no marker beside them
    measured.parent.mkdir()
    shutil.copyfile(theirs, measured)
    build = tmp_path / "build"
    result = invoke("build", ours, measured, "--out", build, *FAST_BUILD)
    assert result.exit_code == 0, result.output
    warning = (
        f"the inputs mix synthetic and other data: 1 ({ours}) written by `ngsim-graphs synth` "
        f"({MARKER_NAME} lists them), 1 ({measured}) not; the build is recorded as not "
        "synthetic, its manifest's synthetic_inputs names the synthetic ones"
    )
    assert warning in " ".join(result.stderr.split())
    manifest = json.loads((build / "manifest.json").read_text())
    assert (manifest["synthetic"], manifest["synthetic_inputs"]) == (False, [str(ours)])
    assert warning in manifest["warnings"]
    document = json.loads(invoke("stats", build, "--json", "--degree-graphs", "5").stdout)
    assert (document["synthetic"], document["synthetic_inputs"]) == (False, [str(ours)])
    table = invoke("stats", build, "--degree-graphs", "5").stdout
    assert table.startswith(f"{build}: 1 of 2 inputs are {SYNTHETIC_LABEL} (the manifest's")


def test_a_manifest_made_before_the_record_still_reads(tiny_build: Path, tmp_path: Path) -> None:
    """Without the synthetic keys (an earlier build), synth's markers beside the inputs tell."""
    build = Path(shutil.copytree(tiny_build, tmp_path / "build"))
    manifest = json.loads((build / "manifest.json").read_text())
    for key in ("synthetic", "synthetic_inputs"):
        del manifest[key]
    (build / "manifest.json").write_text(json.dumps(integrity.with_checksum(manifest)))
    document = json.loads(invoke("stats", build, "--json", "--degree-graphs", "5").stdout)
    assert document["synthetic"] is True
    assert document["synthetic_inputs"] == [r["path"] for r in manifest["inputs"]]
