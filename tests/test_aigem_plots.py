"""The pictures: curves.png and `aigem evaluate --plots`. Every file is a PNG, and what is drawn
is the data: the log's losses, the recorded baseline, one point per future step, one ECDF step
per target, the paper's points labelled as the paper's."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import to_hex
from test_synth_marker import label_pixels
from typer.testing import CliRunner

from aigem.evaluation.evaluate import evaluate
from aigem.evaluation.results import Evaluation
from aigem.figures.pictures import FIGURES, OWNED, SCENES, describe_build, write_evaluation_plots
from aigem.figures.plots import error_by_horizon, error_by_region, final_error_distribution
from aigem.runs import folder as runs
from aigem.runs import run_log
from aigem.runs.curves import VALIDATION_LABEL, curves_figure, curves_png
from aigem.runs.run_log import EpochRow
from ngsim_cli.aigem import app
from ngsim_graphs import palette
from ngsim_graphs.errors import NgsimOutputError
from ngsim_graphs.synth.marker import SYNTHETIC_LABEL

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
ROWS = [
    EpochRow(epoch=1, train_loss_m2=9.0, val_loss_m2=5.0, best_epoch=1),
    EpochRow(epoch=2, train_loss_m2=4.0, val_loss_m2=3.0, best_epoch=2),
    EpochRow(epoch=3, train_loss_m2=2.0, val_loss_m2=4.0, best_epoch=2),
]


@pytest.fixture
def run(tiny_horizons_run: Path) -> Path:
    """A 1 s + 2 s run of one epoch; RUN/h2s alone is a single-horizon run."""
    return tiny_horizons_run


@pytest.fixture(scope="module")
def results(tiny_horizons_run: Path) -> dict[str, Evaluation]:
    """The 2 s model alone ("single") and the 1 s + 2 s run ("several"), on the test split."""
    return {
        "single": evaluate(tiny_horizons_run / "h2s", None, "test", "cpu", resamples=0),
        "several": evaluate(tiny_horizons_run, None, "test", "cpu", resamples=0),
    }


def _is_png(path: Path, min_bytes: int = 10_000) -> bool:
    data = path.read_bytes()
    return data.startswith(PNG_SIGNATURE) and len(data) > min_bytes


def _line(axes, label: str):
    (line,) = [line for line in axes.get_lines() if line.get_label() == label]
    return line


def test_curves_draw_the_log_the_best_epoch_and_the_baseline() -> None:
    axes = curves_figure(ROWS, 3.5, 2.0).axes[0]
    assert _line(axes, VALIDATION_LABEL).get_ydata().tolist() == [5.0, 3.0, 4.0]
    assert _line(axes, "best: epoch 2, validation 3 m²").get_xydata().tolist() == [[2.0, 3.0]]
    baseline = _line(axes, "constant velocity, validation (3.5 m²)")
    assert set(baseline.get_ydata()) == {3.5}
    assert all(tick == int(tick) for tick in axes.get_xticks())  # whole epochs
    without = curves_figure(ROWS, None, 2.0).axes[0]
    assert not [line for line in without.get_lines() if "constant" in line.get_label()]
    assert curves_png(ROWS[:1], None, None).startswith(PNG_SIGNATURE)


def test_curves_draw_a_scheduled_learning_rate_on_a_second_axis() -> None:
    rates = [0.5e-3, 1e-3, 0.25e-3]
    figure = curves_figure(
        [replace(r, learning_rate=v) for r, v in zip(ROWS, rates, strict=True)], None, 2.0
    )
    assert len(figure.axes) == 2
    assert figure.axes[1].get_lines()[0].get_ydata().tolist() == rates
    constant = [replace(r, learning_rate=1e-3) for r in ROWS]
    assert len(curves_figure(constant, None, 2.0).axes) == 1  # nothing to show
    assert len(curves_figure(ROWS, None, 2.0).axes) == 1  # a run of an older aigem


def test_fit_draws_each_members_curves_with_its_baseline(run: Path) -> None:
    for member in ("h1s", "h2s"):
        assert _is_png(run / member / runs.CURVES)
        assert run_log.read_baseline(run / member) is not None
    assert run_log.read_baseline(run / "h1s") < run_log.read_baseline(run / "h2s")


def test_evaluation_figures_draw_the_evaluations_numbers(run: Path) -> None:
    single = evaluate(run / "h2s", None, "test", "cpu")
    rmse, mean = error_by_horizon(single, "a label").axes
    ours = _line(rmse, "AiGem, this run's 2 s model")
    assert len(ours.get_xdata()) == single.horizon_steps == 10
    np.testing.assert_allclose(ours.get_xdata(), np.arange(1, 11) * 0.2)
    np.testing.assert_allclose(ours.get_ydata(), single.steps["model"]["all"]["rmse_m"])
    cv = _line(mean, "constant velocity, same targets").get_ydata()
    np.testing.assert_allclose(cv, single.steps["constant_velocity"]["all"]["mean_error_m"])
    front = error_by_region(single, "a label").axes[0]
    np.testing.assert_allclose(
        _line(front, "AiGem, this run's 2 s model: mean error").get_ydata(),
        np.array(single.steps["model"]["front"]["mean_error_m"], dtype=float),
    )
    ecdf = final_error_distribution(single, "a label").axes[0].get_lines()[0]
    assert len(ecdf.get_xdata()) == len(single.final.model_m)
    several = evaluate(run, None, "test", "cpu")
    rmse = error_by_horizon(several, "a label").axes[0]
    diamonds = _line(rmse, "AiGem at h s from its h s model (the paper's protocol)")
    assert diamonds.get_ydata().tolist() == [
        several.model["all"]["rmse_1s_m"],
        several.model["all"]["rmse_2s_m"],
    ]
    assert len(_line(rmse, "AiGem, this run's 2 s model").get_xdata()) == 10
    for draw in (error_by_horizon, error_by_region, final_error_distribution):
        labels = [line.get_label() for axes in draw(several, "x").axes for line in axes.get_lines()]
        assert all("(published, NGSIM)" in label for label in labels if "NGSIM" in label), labels


def test_describe_build_names_synthetic_data(tiny_build: Path) -> None:
    label = describe_build(tiny_build)
    assert label == f'build folder "{tiny_build.name}": 1 recording of us-101, {SYNTHETIC_LABEL}'


def test_one_epochs_curves_show_the_point_on_a_whole_epoch_clear_of_the_legend() -> None:
    figure = curves_figure(ROWS[:1], 3.5, 2.0)
    axes = figure.axes[0]
    low, high = axes.get_xlim()
    assert [tick for tick in axes.get_xticks() if low <= tick <= high] == [1.0]  # not 0.5..1.5
    assert axes.get_legend() is None and len(figure.legends) == 1  # below the axes, not on them
    FigureCanvasAgg(figure).draw()
    legend = figure.legends[0].get_window_extent()
    point = axes.transData.transform((1.0, 5.0))
    assert not legend.contains(*point) and axes.bbox.contains(*point)
    validation, best = _line(axes, VALIDATION_LABEL), _line(axes, "best: epoch 1, validation 5 m²")
    assert validation.get_zorder() > best.get_zorder()  # the star marks the point, never hides it


def test_every_picture_of_a_synthetic_build_says_so(
    run: Path, tiny_build: Path, tmp_path: Path
) -> None:
    folder = tmp_path / "pictures"
    result = CliRunner().invoke(
        app, ["evaluate", str(run / "h2s"), "--device", "cpu", "--plots", str(folder)]
    )
    assert result.exit_code == 0, result.output
    for name in (*(f"{name}.png" for name in FIGURES), SCENES):
        assert label_pixels(folder / name) > 200, name
    assert label_pixels(run / "h2s" / runs.CURVES) > 200  # fit's curves
    result, label = evaluate(run / "h2s", device_choice="cpu"), describe_build(tiny_build)
    footer = error_by_horizon(result, label).texts[0].get_text().replace("\n", " ")
    trained = "AiGem trained 1 of 1 epoch."  # aigem.runs.course
    assert footer == f"Lines: test split ({result.samples} samples) of {label}. {trained}"
    document = CliRunner().invoke(app, ["evaluate", str(run), "--device", "cpu", "--json"])
    assert json.loads(document.stdout)["synthetic"] is True


@pytest.mark.slow
def test_cli_plots_of_a_multi_horizon_and_a_single_run(run: Path, tmp_path: Path) -> None:
    folder = tmp_path / "pictures"
    folder.mkdir()
    (folder / "notes.txt").write_text("mine")
    result = CliRunner().invoke(
        app, ["evaluate", str(run), "--device", "cpu", "--plots", str(folder)]
    )
    assert result.exit_code == 0, result.output
    assert f"Plots in {folder}" in result.stdout.replace("\n", "")
    first = {name: (folder / f"{name}.png").read_bytes() for name in FIGURES}
    assert all(_is_png(folder / f"{name}.png", 20_000) for name in FIGURES)
    assert _is_png(folder / SCENES, 50_000)
    # A single-horizon run into the same folder: our pictures replaced, the rest left alone.
    single = CliRunner().invoke(
        app, ["evaluate", str(run / "h2s"), "--device", "cpu", "--json", "--plots", str(folder)]
    )
    assert single.exit_code == 0, single.output
    assert single.stdout.startswith("{")  # --json: the document only
    assert (folder / "error_by_horizon.png").read_bytes() != first["error_by_horizon"]
    assert (folder / "notes.txt").read_text() == "mine"
    assert sorted(p.name for p in folder.iterdir()) == sorted(
        ["notes.txt", OWNED, SCENES, *(f"{name}.png" for name in FIGURES)]
    )


def test_plots_never_replace_a_picture_that_is_not_ours(run: Path, tmp_path: Path) -> None:
    """A scenes.png of someone else's stops the call before anything is written."""
    folder = tmp_path / "pictures"
    folder.mkdir()
    (folder / SCENES).write_bytes(b"mine")
    result = evaluate(run / "h2s", split="val", device_choice="cpu")
    with pytest.raises(NgsimOutputError, match="was not written by `aigem evaluate --plots`"):
        write_evaluation_plots(result, folder, run / "h2s")
    assert sorted(p.name for p in folder.iterdir()) == [SCENES]
    assert (folder / SCENES).read_bytes() == b"mine"


@pytest.mark.slow
def test_plots_remove_their_own_stale_scenes(run: Path, tmp_path: Path) -> None:
    """A call that draws no scenes (as with --other-build) removes the scenes of an earlier call:
    the folder never mixes two evaluations."""
    folder = tmp_path / "pictures"
    result = evaluate(run / "h2s", split="val", device_choice="cpu")
    write_evaluation_plots(result, folder, run / "h2s")
    assert _is_png(folder / SCENES, 50_000)
    written = write_evaluation_plots(result, folder, run_dir=None)
    assert sorted(p.name for p in written) == sorted(f"{name}.png" for name in FIGURES)
    assert sorted(p.name for p in folder.iterdir()) == sorted(
        [OWNED, *(f"{name}.png" for name in FIGURES)]
    )


def test_plots_into_a_file_is_one_error_line(run: Path, tmp_path: Path) -> None:
    (tmp_path / "taken").write_text("")
    result = CliRunner().invoke(
        app, ["evaluate", str(run / "h1s"), "--device", "cpu", "--plots", str(tmp_path / "taken")]
    )
    assert result.exit_code == 1 and result.stderr.startswith(f"error: {tmp_path / 'taken'}: ")
    assert result.stderr.count("\n") == 1


def test_evaluate_help_names_plots_within_80_columns() -> None:
    result = CliRunner(env={"COLUMNS": "80"}).invoke(app, ["evaluate", "--help"])
    assert result.exit_code == 0 and "--plots DIR" in result.stdout
    assert max(len(line) for line in result.stdout.splitlines()) <= 80


def test_error_by_horizon_ends_at_the_last_horizon_and_names_models_only_of_several(
    results: dict[str, Evaluation],
) -> None:
    """A 2 s model: both axes end at 2 s, the published points beyond it (and the FDE at 5 s)
    left out; no "2 s model" written on a run of one model, each model named once on two."""
    rmse, mean = error_by_horizon(results["single"], "a label").axes
    assert rmse.get_xlim() == mean.get_xlim() == (0.0, 2.0)
    published = [line for line in rmse.get_lines() if "published" in line.get_label()]
    assert len(published) == 7  # the paper's six rows and constant velocity's
    assert all(line.get_xdata().tolist() == [1, 2] for line in published)
    assert not [line for line in mean.get_lines() if "published" in line.get_label()]
    assert list(rmse.texts) == [] and len(rmse.get_lines()) == 2 + 7  # no diamonds either
    rmse = error_by_horizon(results["several"], "a label").axes[0]
    assert [text.get_text() for text in rmse.texts] == ["1 s model", "2 s model"]


def test_the_models_have_their_colours_in_every_figure(results: dict[str, Evaluation]) -> None:
    result = results["single"]
    figures = (
        error_by_horizon(result, "x"),
        error_by_region(result, "x"),
        final_error_distribution(result, "x"),
    )
    for figure in figures:
        for axes in figure.axes:
            for line in axes.get_lines():
                label, colour = line.get_label(), to_hex(line.get_color())
                if label.startswith("AiGem, this run"):
                    assert colour == to_hex(palette.AIGEM), label
                elif label.startswith("constant velocity") and "published" not in label:
                    assert colour == to_hex(palette.CONSTANT_VELOCITY), label
    markers = {line.get_label(): line for line in figures[0].axes[0].get_lines()}
    assert to_hex(markers["AiGem (published, NGSIM)"].get_mec()) == to_hex(palette.AIGEM)
    assert to_hex(markers["CS-LSTM (published, NGSIM)"].get_mec()) == to_hex(palette.PUBLISHED)
    assert to_hex(markers["constant velocity (published, NGSIM)"].get_mec()) == to_hex(
        palette.CONSTANT_VELOCITY
    )
    curves = curves_figure(ROWS, 3.5, 2.0).axes[0]
    assert to_hex(_line(curves, VALIDATION_LABEL).get_color()) == to_hex(palette.AIGEM)
    baseline = _line(curves, "constant velocity, validation (3.5 m²)")
    assert to_hex(baseline.get_color()) == to_hex(palette.CONSTANT_VELOCITY)


def test_the_legend_and_the_synthetic_label_cover_no_title_data_or_footer(
    results: dict[str, Evaluation],
) -> None:
    """The tiny build is synthetic: the label sits above the title, never on it; the legend
    lies between the axes and the footer."""
    for draw in (error_by_horizon, error_by_region, final_error_distribution):
        figure = draw(results["single"], "a label")
        FigureCanvasAgg(figure).draw()
        footer, *_, label = figure.texts
        assert label.get_text().startswith("SYNTHETIC")
        (title,) = [
            t.get_window_extent() for t in figure.texts if t.get_text() == figure.get_suptitle()
        ]
        assert label.get_window_extent().y0 > (title.y0 + title.y1) / 2  # its empty line
        assert figure.get_suptitle().startswith("\n")  # the label's line
        for axes in figure.axes:
            assert not title.overlaps(axes.get_tightbbox())
            for legend in figure.legends:
                assert not legend.get_window_extent().overlaps(axes.get_tightbbox())
        for legend in figure.legends:
            assert not legend.get_window_extent().overlaps(footer.get_window_extent())
