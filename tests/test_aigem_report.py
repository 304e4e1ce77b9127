"""`aigem paper`'s report from hand-made evaluations: which number lands where, SYNTHETIC on
every table and figure of synthetic data, the timings apart, report.json written last."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.colors import to_hex
from matplotlib.container import BarContainer
from matplotlib.figure import Figure

from aigem.evaluation.results import Evaluation, paper_rows
from aigem.intervals import t_975
from aigem.paper.report import paper_report, write_report
from aigem.paper.report_cells import NOISES_SAID
from aigem.paper.report_parts import table1
from aigem.paper.report_plots import CONSTANT_VELOCITY_TICK, draw_report, report_figures
from aigem.paper.report_tables import NO_FIT_DIFFERENCE, table1_lines
from aigem.paper.report_text import ONE_SEED, TIME_HEADING, UNFINISHED, report_markdown
from aigem.runs.run_log import EpochRow
from ngsim_graphs import palette

SETTINGS = {
    "inputs": [{"path": "/data/a.txt", "size_bytes": 1000}],
    "config": {"epochs": 3, "patience_epochs": None, "seed": 0, "batch_size": 32},
}
MODELS = {f"h{s}s": {"epochs_done": 3, "best_epoch": 2, "stopped": "epochs"} for s in range(1, 6)}


def rows(rmse: list[float], ade: float, fde: float, n: int = 10) -> dict[str, float]:
    row = {"ade_m": ade, "fde_m": fde}
    for s, value in enumerate(rmse, start=1):
        row[f"rmse_{s}s_m"] = value
        row[f"n_{s}s"] = n
    return row


def evaluation(base: float, synthetic: bool = True, cv_base: float | None = None) -> Evaluation:
    """RMSE base + s at s seconds overall, base + s + 0.1/0.2/0.3 front/mid/rear; constant
    velocity's 10 times cv_base + s (cv_base: base unless given, the same for every seed of a
    fit); ADE base, FDE 2 * base."""
    rmse = [base + s for s in range(1, 6)]
    model = {"all": rows(rmse, base, 2 * base, n=12)}
    for shift, region in ((0.1, "front"), (0.2, "mid"), (0.3, "rear")):
        model[region] = rows([v + shift for v in rmse], base, 2 * base, n=4)
    cv_base = base if cv_base is None else cv_base
    cv_rmse = [cv_base + s for s in range(1, 6)]
    cv = {"all": rows([10 * v for v in cv_rmse], 10 * cv_base, 20 * cv_base, n=12)}
    for shift, region in ((1, "front"), (2, "mid"), (3, "rear")):
        cv[region] = rows([10 * v + shift for v in cv_rmse], 10 * cv_base, 20 * cv_base, n=4)
    return Evaluation(
        split="test",
        horizons_s=(1.0, 2.0, 3.0, 4.0, 5.0),
        samples=7,
        parameters=74_242,
        model=model,
        constant_velocity=cv,
        sources={},
        members={},
        build_dir="/somewhere/builds/dmin-25m",
        same_build=True,
        synthetic=synthetic,
        protocol="aigem",
        protocol_description="",
    )


SETTINGS_OF = {
    "dmin-25m": (25.0, True),
    "dmin-25m-no-concat": (25.0, False),
    "dmin-0m": (0.0, True),
    "dmin-50m": (50.0, True),
}


def fits(seeds: tuple[int, ...] = (0,)) -> dict:
    """Each fit's settings and its runs, one per seed (the first seed's run its own name)."""
    return {
        name: {
            "d_min_m": d_min_m,
            "concat_position": concat,
            "runs": [
                {"seed": s, "run": name if s == seeds[0] else f"{name}-seed{s}", "models": MODELS}
                for s in seeds
            ],
        }
        for name, (d_min_m, concat) in SETTINGS_OF.items()
    }


BASES = {"dmin-25m": 1.0, "dmin-25m-no-concat": 2.0, "dmin-0m": 3.0, "dmin-50m": 4.0}
CURVE_ROWS = {
    "h1s": [
        EpochRow(epoch=1, train_loss_m2=4.0, val_loss_m2=9.0, best_epoch=1, train_seconds=5),
        EpochRow(epoch=2, train_loss_m2=1.0, val_loss_m2=16.0, best_epoch=1),
    ]
}
PARTS = ("table", "dmin", "concat", "curves", "regions")


def report(
    synthetic: bool = True,
    parts: tuple[str, ...] = PARTS,
    unfinished: tuple[str, ...] = (),
    partly: bool = False,
) -> dict:
    """The report of one seed, seed 0."""
    evaluations = {name: [evaluation(base, synthetic)] for name, base in BASES.items()}
    return paper_report(
        SETTINGS, parts, (0,), fits(), evaluations, [CURVE_ROWS], unfinished, partly
    )


def bare(cells: list) -> list:
    """Cells without bounds (one seed) as their numbers; a cell with bounds fails."""
    assert all(cell is None or cell["low"] is cell["high"] is None for cell in cells)
    return [None if cell is None else cell["value"] for cell in cells]


def bare_row(row: dict) -> dict:
    return {
        key: bare([value])[0] if isinstance(value, dict) else value for key, value in row.items()
    }


def test_table1_holds_the_paper_fits_numbers_constant_velocity_and_every_published_row() -> None:
    table = report()["table1"]
    assert bare_row(table["ours"]["AiGem (this run)"]) == {
        "ade_m": 1.0,
        "fde_m": 2.0,
        **{f"rmse_{s}s_m": 1.0 + s for s in range(1, 6)},
        "params_k": 74.2,
    }
    assert table["ours"]["constant velocity"]["rmse_5s_m"] == {
        "value": 60.0,
        "low": None,
        "high": None,
    }
    assert bare_row(table["ours"]["constant velocity"])["ade_m"] == 10.0
    assert table["targets"] == [12] * 5
    assert {k: v for k, v in table["published"].items() if k in paper_rows()} == paper_rows()
    names = list(table["published"])
    assert names == [
        "CS-LSTM (paper)",
        "GRIP++ (paper)",
        "STA-LSTM (paper)",
        "DeepTrack (paper)",
        "GSTCN (paper)",
        "AiGem (paper)",
        "constant velocity (CS-LSTM paper)",  # Deo and Trivedi 2018, beside Table 1
    ]
    cv = table["published"]["constant velocity (CS-LSTM paper)"]
    assert [cv[f"rmse_{s}s_m"] for s in range(1, 6)] == [0.73, 1.78, 3.13, 4.78, 6.68]
    assert cv["ade_m"] is None and "Deo, Trivedi" in table["published_source"]
    assert table["published"]["STA-LSTM (paper)"]["rmse_1s_m"] == 0.37
    assert "GRIP++ (paper)" in table["published_notes"]


def test_the_ablations_are_told_by_each_fits_settings() -> None:
    document = report()
    assert {d: bare(cells) for d, cells in document["dmin"].items()} == {
        "0": [4.0, 5.0, 6.0, 7.0, 8.0],
        "25": [2.0, 3.0, 4.0, 5.0, 6.0],
        "50": [5.0, 6.0, 7.0, 8.0, 9.0],
    }
    assert {k: bare(cells) for k, cells in document["concat"].items()} == {
        "with": [2.0, 3.0, 4.0, 5.0, 6.0],
        "without": [3.0, 4.0, 5.0, 6.0, 7.0],
    }
    assert bare(document["regions"]["rmse_m"]["front"]) == pytest.approx([2.1, 3.1, 4.1, 5.1, 6.1])
    assert bare(document["regions"]["rmse_m"]["rear"]) == pytest.approx([2.3, 3.3, 4.3, 5.3, 6.3])
    assert document["regions"]["targets"]["mid"] == [4] * 5
    assert document["fits"]["dmin-0m"]["test_samples"] == 7


def test_every_comparison_holds_constant_velocity_and_the_published_rows() -> None:
    document = report()
    assert bare(document["dmin_constant_velocity"]["0"]) == [40.0, 50.0, 60.0, 70.0, 80.0]
    assert bare(document["concat_constant_velocity"]["without"]) == [30.0, 40.0, 50.0, 60.0, 70.0]
    assert bare(document["regions"]["constant_velocity_rmse_m"]["rear"]) == [23, 33, 43, 53, 63]
    text = report_markdown(document, {})
    published_aigem = (
        "| AiGem (paper, Table 1: d_min 25 m, concatenation, all actors), published NGSIM "
        "| 0.61 | 1.02 | 1.27 | 1.84 | 1.95 |"
    )
    published_cv = (
        "| constant velocity (CS-LSTM paper, all actors), published NGSIM "
        "| 0.73 | 1.78 | 3.13 | 4.78 | 6.68 |"
    )
    sections = text.split("## ")
    for title in ("d_min ablation", "Output concatenation", "Front / mid / rear"):
        (section,) = [part for part in sections if part.startswith(title)]
        assert published_aigem in section and published_cv in section, title
        assert "Deo, Trivedi" in section and "figures without numbers" in section
    assert "| 0: constant velocity, same targets | 40.00 | 50.00 | 60.00 | 70.00 | 80.00 |" in text
    assert "| without: constant velocity, same targets | 30.00 | 40.00 |" in text
    assert (
        "| rear (y < -15 m): constant velocity | 23.00 | 33.00 | 43.00 | 53.00 | 63.00 | 4 |"
        in text
    )
    (curves,) = [part for part in sections if part.startswith("Training curves")]
    assert "dropout active" in curves and "dropout off" in curves


def test_the_run_lines_say_how_many_of_the_epochs_and_how_to_continue() -> None:
    cut = {f"h{s}s": {"epochs_done": 1, "best_epoch": 1, "stopped": "time limit"} for s in (1, 2)}
    document = report(unfinished=("dmin-0m",))
    document["fits"]["dmin-0m"]["runs"][0]["models"] = cut
    text = report_markdown(document, {})
    assert (
        "| dmin-0m | 0 | yes | 7 | h1s: trained 1 of 3 (best 1); h2s: trained 1 of 3 (best 1); "
        "stopped by time limit; UNFINISHED: the same `aigem paper` command continues it |"
    ) in text
    assert "h1s: trained 3 of 3 (best 2)" in text and "stopped by epochs |" in text


def test_curves_are_the_square_root_of_the_logged_mse() -> None:
    curve = report()["curves"]["h1s"]
    assert curve["seeds"] == [
        {"seed": 0, "epoch": [1, 2], "train_rmse_m": [2.0, 1.0], "val_rmse_m": [3.0, 4.0]}
        | {"best_epoch": 1}
    ]
    assert curve["epoch"] == [1, 2] and curve["best_epoch"] == [1]
    assert bare(curve["train_rmse_m"]) == [2.0, 1.0] and bare(curve["val_rmse_m"]) == [3.0, 4.0]
    assert bare(list(curve["at_best"].values())) == [2.0, 3.0]  # at epoch 1, the model kept


def test_only_the_parts_asked_for_are_reported() -> None:
    document = report(parts=("concat",))
    assert "concat" in document and not {"table1", "dmin", "curves", "regions"} & set(document)


def test_markdown_says_synthetic_on_every_table_and_keeps_the_time_last() -> None:
    text = report_markdown(report(), {"builds": 1.25, "total": 9.0})
    headings = [line for line in text.splitlines() if line.startswith("## ")]
    parts = [h for h in headings if h not in ("## Runs", TIME_HEADING)]
    assert len(parts) == 5 and all(h.endswith("(SYNTHETIC)") for h in parts)
    assert text.splitlines()[0].endswith("(SYNTHETIC)")
    assert headings[-1] == TIME_HEADING and text.rstrip().endswith("- total: 9.0 s")
    assert "| AiGem (this run) | 1.00 | 2.00 | 2.00 | 3.00 | 4.00 | 5.00 | 6.00 | 74.2 |" in text
    assert "| GRIP++ (paper) | 1.61 | – | 0.38 |" in text  # no FDE published
    assert (
        "Inputs: 1 file, 1,000 bytes. Training: up to 3 epochs per model (the paper trains 100; "
        "this call 3), batch 32, seed 0," in text
    )
    assert "| 0 | 4.00 | 5.00 | 6.00 | 7.00 | 8.00 |" in text
    assert "| h1s | 2 | 1 | 2.00 | 3.00 |" in text  # the best epoch's RMSE
    plain = report_markdown(report(synthetic=False), {})
    assert "SYNTHETIC" not in plain


def test_a_report_of_fits_the_time_limit_stopped_says_unfinished_everywhere() -> None:
    assert report()["finished"] and report()["unfinished_fits"] == []
    document = report(synthetic=False, unfinished=("dmin-0m", "dmin-50m"))
    assert not document["finished"] and document["unfinished_fits"] == ["dmin-0m", "dmin-50m"]
    text = report_markdown(document, {})
    lines = text.splitlines()
    assert lines[0].endswith("(UNFINISHED)")
    assert lines[2] == f"**{UNFINISHED}** (unfinished fits: dmin-0m, dmin-50m)."
    headings = [line for line in lines if line.startswith("## ")]
    parts = [h for h in headings if h not in ("## Runs", TIME_HEADING)]
    assert len(parts) == 5 and all(h.endswith("(UNFINISHED)") for h in parts)
    both = report_markdown(report(unfinished=("dmin-0m",)), {})
    assert both.splitlines()[0].endswith("(SYNTHETIC, UNFINISHED)")
    assert "UNFINISHED" not in report_markdown(report(), {})
    figures = report_figures(document)
    plain = report_figures(report(synthetic=False))
    assert sorted(figures) == sorted(plain)
    assert all(figures[name] != plain[name] for name in figures)  # each says it


def test_inputs_partly_synthetic_are_said_on_every_table_and_figure() -> None:
    document = report(synthetic=False, partly=True)
    assert document["partly_synthetic"] and not document["synthetic"]
    assert "PARTLY SYNTHETIC" in document["data"]
    text = report_markdown(document, {})
    assert text.splitlines()[2].startswith("**PARTLY SYNTHETIC**: every number of this call")
    headings = [line for line in text.splitlines() if line.startswith(("# ", "## "))]
    parts = [h for h in headings if h not in ("## Runs", TIME_HEADING)]
    assert len(parts) == 6 and all(h.endswith("(PARTLY SYNTHETIC)") for h in parts)
    assert "| AiGem (this run) |" in text and "| this call, PARTLY SYNTHETIC data |" in text
    plain = report_figures(report(synthetic=False))
    assert all(png != plain[name] for name, png in report_figures(document).items())
    assert not report(synthetic=True, partly=True)["partly_synthetic"]  # all synthetic: SYNTHETIC


def test_a_horizon_without_targets_is_shown_as_a_dash_not_dropped() -> None:
    document = report()
    document["table1"]["targets"][2] = None
    document["regions"]["targets"]["rear"][-1] = None
    text = report_markdown(document, {})
    assert "Targets at 1..5 s: 12, 12, –, 12, 12." in text
    assert "| rear (y < -" in text and text.split("| rear (y < -")[1].split("\n")[0].endswith(
        "| – |"
    )


def test_write_report_writes_the_figures_and_report_json_last_with_the_timings(
    tmp_path: Path,
) -> None:
    (tmp_path / "figures").mkdir()
    (tmp_path / "figures" / "curves.png").write_bytes(b"an earlier call's")
    document = report(parts=("table", "dmin"))
    written = write_report(tmp_path, document, report_figures(document), {"total": 2.5})
    figures = sorted(p.name for p in (tmp_path / "figures").iterdir())
    assert figures == ["dmin.png", "table1.png"]  # curves.png: of a part this call did not draw
    assert all((tmp_path / "figures" / f).read_bytes()[:4] == b"\x89PNG" for f in figures)
    on_disk = json.loads((tmp_path / "report.json").read_text())
    assert on_disk == written and on_disk["timings"] == {"total": 2.5}
    assert on_disk["figures"] == ["figures/table1.png", "figures/dmin.png"]
    assert (tmp_path / "report.json").stat().st_mtime_ns >= (
        tmp_path / "report.md"
    ).stat().st_mtime_ns
    assert math.isclose(on_disk["table1"]["ours"]["AiGem (this run)"]["rmse_1s_m"]["value"], 2.0)


# ------------------------------------------------------------------------------------------------
# Three seeds: each AiGem number the mean over the seeds and Student's t 95 % interval, each
# ablation's difference to the paper's configuration paired by seed, and what it says in words

SEEDS = (0, 1, 2)
# Each fit's base at seeds 0, 1, 2: the paper's 1.0, 1.2, 1.7 (mean 1.3, sd sqrt(0.13)); the
# ablations' differ from it, seed by seed, by +2.0/+2.1/+1.9 (d_min 0 m: mean 2, sd 0.1),
# +0.5/-0.5/+0.3 (d_min 50 m: mean 0.1, sd sqrt(0.28)) and -1.0/-1.1/-0.9 (without the
# concatenation: mean -1, sd 0.1).
SEED_BASES = {
    "dmin-25m": (1.0, 1.2, 1.7),
    "dmin-0m": (3.0, 3.3, 3.6),
    "dmin-50m": (1.5, 0.7, 2.0),
    "dmin-25m-no-concat": (0.0, 0.1, 0.8),
}
T2 = 4.303  # Student's t 0.975 quantile, 2 degrees of freedom (a statistics table)
SEED_CURVES = [  # each seed's log of its 1 s model: 2, 1 and 2 epochs, best 1, 1 and 2
    CURVE_ROWS["h1s"],
    [EpochRow(epoch=1, train_loss_m2=9.0, val_loss_m2=16.0, best_epoch=1)],
    [
        EpochRow(epoch=1, train_loss_m2=1.0, val_loss_m2=4.0, best_epoch=1),
        EpochRow(epoch=2, train_loss_m2=4.0, val_loss_m2=1.0, best_epoch=2),
    ],
]


def seeds_report(parts: tuple[str, ...] = PARTS) -> dict:
    evaluations = {
        name: [evaluation(base, cv_base=bases[0]) for base in bases]
        for name, bases in SEED_BASES.items()
    }
    curves = [{"h1s": rows} for rows in SEED_CURVES]
    return paper_report(SETTINGS, parts, SEEDS, fits(SEEDS), evaluations, curves)


def cell(mean: float, half: float) -> dict:
    return {
        "value": pytest.approx(mean),
        "low": pytest.approx(mean - half),
        "high": pytest.approx(mean + half),
    }


def test_each_aigem_number_is_the_mean_over_the_seeds_and_its_t_interval() -> None:
    document = seeds_report()
    assert t_975(2) == T2
    half = T2 * math.sqrt(0.13) / math.sqrt(3)  # the paper's fit: sd sqrt(0.13) over 3 seeds
    ours = document["table1"]["ours"]["AiGem (this run)"]
    assert ours["rmse_1s_m"] == cell(2.3, half) and ours["rmse_5s_m"] == cell(6.3, half)
    assert ours["ade_m"] == cell(1.3, half) and ours["fde_m"] == cell(2.6, 2 * half)
    cv = document["table1"]["ours"]["constant velocity"]  # seed-free: no interval
    assert cv["rmse_1s_m"] == {"value": 20.0, "low": None, "high": None}
    assert document["regions"]["rmse_m"]["rear"][0] == cell(2.6, half)
    assert document["dmin"]["0"][0] == cell(4.3, T2 * 0.3 / math.sqrt(3))
    assert document["seeds"] == [0, 1, 2] and document["intervals"]["seeds"] == 3
    # Every seed's own numbers: each run's test rows, its name, constant velocity once.
    runs = document["fits"]["dmin-0m"]["runs"]
    assert [run["run"] for run in runs] == ["dmin-0m", "dmin-0m-seed1", "dmin-0m-seed2"]
    assert [run["test"]["all"]["rmse_1s_m"] for run in runs] == pytest.approx([4.0, 4.3, 4.6])
    assert document["fits"]["dmin-0m"]["constant_velocity_test"]["all"]["rmse_1s_m"] == 40.0


def test_an_ablations_difference_is_paired_by_seed() -> None:
    """d_min 0 m's RMSE alone has the paper's spread (sd 0.3 over the seeds); its difference to
    the paper's configuration, taken seed by seed, only the spread of the differences (0.1)."""
    document = seeds_report()
    assert document["dmin_difference"]["0"] == [cell(2.0, T2 * 0.1 / math.sqrt(3))] * 5
    assert document["dmin_difference"]["50"][2] == cell(0.1, T2 * math.sqrt(0.28) / math.sqrt(3))
    assert document["concat_difference"] == {"without": [cell(-1.0, T2 * 0.1 / math.sqrt(3))] * 5}
    assert set(document["dmin_difference"]) == {"0", "50"}  # the paper's own: no difference
    aigem_cv = document["table1"]["aigem_minus_constant_velocity_rmse_m"]  # 2.3 - 20 at 1 s
    assert aigem_cv[0] == cell(-17.7, T2 * math.sqrt(0.13) / math.sqrt(3))


def test_the_report_says_which_differences_are_beyond_the_noise() -> None:
    text = report_markdown(seeds_report(), {})
    everywhere = "at 1, 2, 3, 4 and 5 s."
    assert (
        "- d_min 0 m against the paper's 25 m: RMSE higher (worse) beyond the training noise "
        f"{everywhere}"
    ) in text
    assert (
        "- d_min 50 m against the paper's 25 m: RMSE within the training noise (the interval "
        f"holds 0) {everywhere}"
    ) in text
    assert (
        "- without the concatenation against with it (the paper's): RMSE lower (better) beyond "
        f"the training noise {everywhere}"
    ) in text
    assert (
        "- AiGem against constant velocity on the same targets: RMSE lower (better) beyond the "
        f"training noise {everywhere}"
    ) in text
    assert NOISES_SAID in text and "test-set noise" not in text.replace(NOISES_SAID, "")
    assert "| 0 | +2.00 [+1.75, +2.25] | +2.00 [+1.75, +2.25] |" in text  # 4.303 * 0.1 / sqrt 3
    assert (
        "| AiGem (this run) | 1.30 [0.40, 2.20] | 2.60 [0.81, 4.39] | 2.30 [1.40, 3.20] |" in text
    )
    assert "| 0: constant velocity, same targets | 40.00 | 50.00 |" in text  # seed-free
    assert "Each fit was trained 3 times, at seeds 0, 1, 2" in text and ONE_SEED not in text
    assert "batch 32, seeds 0, 1, 2, patience none" in text
    assert "| dmin-0m-seed2 | 2 | 0 | yes | 7 |" in text  # a run per seed, its seed said


def test_curves_over_seeds_are_the_mean_of_the_seeds_that_reached_each_epoch() -> None:
    document = seeds_report()
    curve = document["curves"]["h1s"]
    assert curve["epoch"] == [1, 2] and curve["best_epoch"] == [1, 1, 2]
    assert curve["train_rmse_m"] == [cell(2.0, T2 / math.sqrt(3)), cell(1.5, 12.706 * 0.5)]
    assert curve["at_best"]["val_rmse_m"] == cell(8 / 3, T2 * math.sqrt(7 / 3) / math.sqrt(3))
    assert [seed["epoch"] for seed in curve["seeds"]] == [[1, 2], [1], [1, 2]]
    text = report_markdown(document, {})
    assert curve["at_best"]["train_rmse_m"] == cell(7 / 3, T2 * math.sqrt(1 / 3) / math.sqrt(3))
    assert "| h1s | 2, 1, 2 | 1, 1, 2 | 2.33 [0.90, 3.77] | 2.67 [-1.13, 6.46] |" in text
    figures = report_figures(document)  # the bands and error bars drawn
    assert sorted(figures) == ["concat", "curves", "dmin", "regions", "table1"]


def test_one_seed_says_intervals_need_more_seeds_and_holds_no_difference_rows() -> None:
    document = report()
    assert document["intervals"] is None and document["seeds"] == [0]
    assert bare(document["dmin_difference"]["0"]) == [2.0] * 5  # kept in report.json
    text = report_markdown(document, {})
    assert ONE_SEED in text and "beyond the noise" not in text and "minus the paper's" not in text


def test_noise_words_per_horizon() -> None:
    from aigem.paper.report_cells import noise_sentence, shown

    cells = [
        {"value": -0.5, "low": -0.9, "high": -0.1},
        {"value": 0.2, "low": -0.1, "high": 0.5},
        None,
        {"value": 0.3, "low": 0.1, "high": 0.5},
        {"value": 0.0, "low": 0.0, "high": 0.4},  # 0 on the bound: held
    ]
    assert noise_sentence("X", cells) == (
        "X: RMSE lower (better) beyond the training noise at 1 s; higher (worse) beyond the "
        "training noise at 4 s; within the training noise (the interval holds 0) at 2 and 5 s; "
        "no number at 3 s."
    )
    assert noise_sentence("X", cells[:2] + cells[3:] + [None], "bootstrap") == (
        "X: RMSE lower (better) beyond the test-set noise at 1 s; higher (worse) beyond the "
        "test-set noise at 3 s; within the test-set noise (the interval holds 0) at 2 and 4 s; "
        "no number at 5 s."
    )
    unknown = [{"value": 0.3, "low": None, "high": None}] * 5
    assert noise_sentence("X", unknown) == (
        "X: no interval (one seed), so no telling this difference from the training noise."
    )
    assert shown(cells[0], signed=True) == "-0.50 [-0.90, -0.10]" and shown(None) == "–"
    assert shown(unknown[0]) == "0.30" and shown(1.234) == "1.23"


def test_one_seed_table1_takes_its_intervals_from_the_evaluations_bootstrap() -> None:
    """With one seed, Table 1's cells are the paper fit's bootstrap intervals over its test
    samples: AiGem's, constant velocity's and their paired difference, said as such."""
    from dataclasses import replace

    from aigem.intervals import Interval, Paired, SampleIntervals

    def paired(model: float, cv: float) -> Paired:
        return Paired(
            Interval(model, model - 0.1, model + 0.2),
            Interval(cv, cv - 0.3, cv + 0.3),
            Interval(model - cv, model - cv - 0.5, model - cv + 0.5),
        )

    one = evaluation(1.0)  # RMSE 2..6 m, constant velocity's 20..60 m, ADE 1, FDE 2 (CV 10, 20)
    metrics = {f"rmse_{s}s_m": paired(1.0 + s, 10 * (1.0 + s)) for s in range(1, 6)}
    metrics |= {"ade_m": paired(1.0, 10.0), "fde_m": paired(2.0, 20.0)}
    one = replace(one, intervals=SampleIntervals(1000, 0, 7, metrics))
    table = table1([one])
    assert table["intervals"]["kind"] == "bootstrap" and table["intervals"]["samples"] == 7
    aigem = table["ours"]["AiGem (this run)"]
    assert aigem["rmse_3s_m"] == {"value": 4.0, "low": 3.9, "high": 4.2}
    assert aigem["params_k"] == 74.2
    assert table["ours"]["constant velocity"]["ade_m"] == {"value": 10.0, "low": 9.7, "high": 10.3}
    assert table["aigem_minus_constant_velocity_rmse_m"][0] == {
        "value": -18.0, "low": -18.5, "high": -17.5
    }  # fmt: skip
    document = {"table1": table, "synthetic": True, "partly_synthetic": False, "finished": True}
    lines = table1_lines(document)
    text = "\n".join(lines)
    assert "| AiGem (this run) | 1.00 [0.90, 1.20] | 2.00 [1.90, 2.20] | 2.00 [1.90, 2.20]" in text
    assert "lower (better) beyond the test-set noise at 1, 2, 3, 4 and 5 s" in text
    assert "1,000 resamples of 7 samples" in text
    assert table1([evaluation(1.0)])["intervals"] is None  # no bootstrap: bare cells


def with_bootstrap(one: Evaluation, half: float = 0.1) -> Evaluation:
    """`one` with bootstrap intervals: AiGem's value - half .. + 2 half, constant velocity's
    - 0.3 .. + 0.3, their difference +- 0.5 (of all actors' RMSE at 1..5 s)."""
    from dataclasses import replace

    from aigem.intervals import Interval, Paired, SampleIntervals

    def paired(model: float, cv: float) -> Paired:
        return Paired(
            Interval(model, model - half, model + 2 * half),
            Interval(cv, cv - 0.3, cv + 0.3),
            Interval(model - cv, model - cv - 0.5, model - cv + 0.5),
        )

    rows, cv = one.model["all"], one.constant_velocity["all"]
    keys = [f"rmse_{s}s_m" for s in range(1, 6)]
    metrics = {key: paired(rows[key], cv[key]) for key in keys}
    return replace(one, intervals=SampleIntervals(1000, 0, 7, metrics))


def test_one_seed_ablations_carry_each_fits_bootstrap_intervals_and_constant_velocity_once() -> (
    None
):
    """With one seed each fit's RMSE and constant velocity's carry the bootstrap's intervals of
    its evaluation, and each fit's AiGem minus constant velocity its paired interval, as Table 1
    does, in words of the test-set noise; constant velocity, alike on every fit's targets, is
    one row; no fit's difference to another, which the training noise decides."""
    evaluations = {
        name: [with_bootstrap(evaluation(base, cv_base=1.0))] for name, base in BASES.items()
    }
    document = paper_report(SETTINGS, PARTS, (0,), fits(), evaluations, [CURVE_ROWS])
    assert document["dmin"]["0"][0] == {"value": 4.0, "low": 3.9, "high": 4.2}
    assert document["dmin_constant_velocity"]["50"][0] == {"value": 20.0, "low": 19.7, "high": 20.3}
    assert document["dmin_minus_constant_velocity"]["0"][0] == {
        "value": -16.0, "low": -16.5, "high": -15.5
    }  # fmt: skip
    assert document["concat_intervals"]["kind"] == "bootstrap"
    assert document["concat_minus_constant_velocity"]["without"][4] == {
        "value": -53.0, "low": -53.5, "high": -52.5
    }  # fmt: skip
    text = report_markdown(document, {})
    (dmin,) = [part for part in text.split("## ") if part.startswith("d_min ablation")]
    assert "| 0 | 4.00 [3.90, 4.20] | 5.00 [4.90, 5.20] |" in dmin
    assert dmin.count("constant velocity, same targets") == 1
    assert (
        "| constant velocity, same targets | 20.00 [19.70, 20.30] | 30.00 [29.70, 30.30] |" in dmin
    )
    assert "| 0 | -16.00 [-16.50, -15.50] |" in dmin  # AiGem minus constant velocity
    assert (
        "- d_min 0 m: AiGem against constant velocity: RMSE lower (better) beyond the test-set "
        "noise at 1, 2, 3, 4 and 5 s."
    ) in dmin
    assert NO_FIT_DIFFERENCE in dmin and "minus the paper's" not in dmin
    assert "- In brackets: 95 % intervals of each fit's one run (percentile bootstrap" in dmin
    (concat,) = [part for part in text.split("## ") if part.startswith("Output concatenation")]
    assert "- without the concatenation: AiGem against constant velocity: RMSE lower" in concat
    assert ONE_SEED in text and NOISES_SAID in text


def test_constant_velocity_stays_a_row_per_fit_where_its_targets_differ() -> None:
    text = report_markdown(report(), {})  # each fit's constant velocity of its own base
    (dmin,) = [part for part in text.split("## ") if part.startswith("d_min ablation")]
    assert dmin.count("constant velocity, same targets") == 3
    assert "| 0: constant velocity, same targets | 40.00 | 50.00 |" in dmin


def test_the_published_rows_say_where_an_rmse_lies_below_the_fde() -> None:
    """At one step the RMSE of a set of predictions is at least their mean distance (the FDE at
    the last step): the paper's AiGem row (1.95 m at 5 s, FDE 2.57 m) breaks it, said beside the
    published rows; a row that keeps it (or gives no FDE) gets no note."""
    from aigem.evaluation.results import below_fde

    table = {
        "kept": {"fde_m": 3.0, "rmse_m": (1.0, 2.0, 3.0, 4.0, 3.0)},
        "no FDE": {"fde_m": None, "rmse_m": (1.0,) * 5},
        "broken": {"fde_m": 2.0, "rmse_m": (1.0, 1.0, 1.0, 1.0, 1.5)},
    }
    assert list(below_fde(table)) == ["broken"]
    assert below_fde(table)["broken"].startswith(
        "its RMSE at 5 s (1.50 m) lies below its FDE (2.00 m), which the paper's own definitions "
        "rule out for one set of predictions"
    )
    assert "1.50 × √2 = 2.12 m ≥ 2.00 m" in below_fde(table)["broken"]
    assert list(below_fde()) == ["AiGem (paper)"]  # of the paper's Table 1
    text = report_markdown(report(), {})
    assert (
        "- AiGem (paper): its RMSE at 5 s (1.95 m) lies below its FDE (2.57 m), which the paper's "
        "own definitions rule out for one set of predictions: at a step the RMSE (the root of the "
        "mean squared distance) is at least the mean distance, the FDE at 5 s; so its RMSE cannot "
        "be the Euclidean one of the predictions its FDE scores"
    ) in text
    assert text.count("Its AiGem row's RMSE at 5 s lies below its FDE") == 3  # ablations, regions


# ------------------------------------------------------------------------------------------------
# The figures: what each draws, inspected on matplotlib's objects


def _footer(figure: Figure) -> str:
    return figure.texts[0].get_text().replace("\n", " ")


def _bars(axes: Axes) -> dict[str, BarContainer]:
    return {c.get_label(): c for c in axes.containers if isinstance(c, BarContainer)}


def _ticks(axes: Axes) -> list[LineCollection]:
    """The constant-velocity ticks over the bars, one collection per series."""
    return [c for c in axes.collections if c.get_label() == CONSTANT_VELOCITY_TICK]


def test_bars_draw_intervals_constant_velocity_and_the_papers_setting_in_aigems_colour() -> None:
    document = seeds_report()
    figure = draw_report(document)["dmin"]
    (axes,) = figure.axes
    bars = _bars(axes)
    assert list(bars) == ["d_min 0 m", "d_min 25 m (the paper's)", "d_min 50 m"]
    paper = bars["d_min 25 m (the paper's)"]
    colours = [to_hex(bar.patches[0].get_facecolor()) for bar in bars.values()]
    assert colours[1] == to_hex(palette.AIGEM) and len(set(colours)) == 3
    cells = document["dmin"]["25"]
    assert [p.get_height() for p in paper.patches] == pytest.approx([c["value"] for c in cells])
    (whiskers,) = paper.errorbar.lines[2]  # each bar's interval, low to high
    assert [tuple(s[:, 1]) for s in whiskers.get_segments()] == [
        pytest.approx((c["low"], c["high"])) for c in cells
    ]
    ticks = _ticks(axes)
    assert len(ticks) == 3 and {to_hex(t.get_color()[0]) for t in ticks} == {
        to_hex(palette.CONSTANT_VELOCITY)
    }
    cv = [c["value"] for c in document["dmin_constant_velocity"]["25"]]
    assert [s[0, 1] for s in ticks[1].get_segments()] == pytest.approx(cv)
    assert "seeds 0, 1, 2" in _footer(figure) and "up to 3 epochs per model" in _footer(figure)
    FigureCanvasAgg(figure).draw()
    legend = figure.legends[0].get_window_extent()
    assert not legend.overlaps(axes.get_tightbbox()) and not legend.overlaps(
        figure.texts[0].get_window_extent()
    )


def test_one_seeds_bars_have_no_error_bar_and_say_why() -> None:
    figures = draw_report(report())
    for name in ("dmin", "concat", "regions"):
        (axes,) = figures[name].axes
        assert all(bar.errorbar is None for bar in _bars(axes).values()), name
        assert len(_ticks(axes)) == len(_bars(axes)), name
        assert "seed 0; one seed: no interval" in _footer(figures[name]), name
    regions = figures["regions"].axes[0]
    assert [to_hex(b.patches[0].get_facecolor()) for b in _bars(regions).values()][1] == to_hex(
        palette.AIGEM
    )


def test_table1_reads_as_the_table_a_panel_per_horizon_a_row_per_model() -> None:
    document = seeds_report()
    figure = draw_report(document)["table1"]
    panels = figure.axes
    assert [axes.get_title() for axes in panels] == ["1 s", "2 s", "3 s", "4 s", "5 s"]
    assert "Table 1" not in figure.get_suptitle() and "RMSE by horizon" in figure.get_suptitle()
    labels = [tick.get_text() for tick in panels[0].get_yticklabels()]
    assert labels[:4] == [
        "AiGem, this call",
        "constant velocity, this call",
        "AiGem, published",
        "constant velocity, published",
    ]
    assert len(labels) == 4 + 5  # and the other five published rows
    ours = document["table1"]["ours"]["AiGem (this run)"]
    for s, axes in enumerate(panels, start=1):
        aigem = axes.containers[0]  # the first row's point and its interval
        assert aigem.lines[0].get_xdata()[0] == pytest.approx(ours[f"rmse_{s}s_m"]["value"])
        assert to_hex(aigem.lines[0].get_color()) == to_hex(palette.AIGEM)
        (whisker,) = aigem.lines[2]
        low, high = whisker.get_segments()[0][:, 0]
        assert (low, high) == pytest.approx(
            (ours[f"rmse_{s}s_m"]["low"], ours[f"rmse_{s}s_m"]["high"])
        )
    assert "seeds 0, 1, 2" in _footer(figure)


def test_the_curves_are_aigems_colour_and_say_the_epochs() -> None:
    figure = draw_report(report())["curves"]
    lines = {line.get_label(): line for line in figure.axes[0].get_lines()}
    assert {to_hex(lines[k].get_color()) for k in ("train", "validation")} == {
        to_hex(palette.AIGEM)
    }
    assert "up to 3 epochs per model, seed 0" in _footer(figure)


def test_one_seeds_ablation_bars_draw_the_bootstrap_and_say_so() -> None:
    """With one seed and each fit's bootstrap (report.json's `dmin_intervals`), the ablation
    bars draw its intervals, and the footer names them the test set's noise."""
    evaluations = {
        name: [with_bootstrap(evaluation(base, cv_base=1.0))] for name, base in BASES.items()
    }
    document = paper_report(SETTINGS, PARTS, (0,), fits(), evaluations, [CURVE_ROWS])
    for name in ("dmin", "concat"):
        figure = draw_report(document)[name]
        (axes,) = figure.axes
        assert all(bar.errorbar is not None for bar in _bars(axes).values()), name
        assert "a bootstrap over the 7 test samples (the test set's noise" in _footer(figure)
    (axes,) = draw_report(document)["dmin"].axes
    (whiskers,) = _bars(axes)["d_min 0 m"].errorbar.lines[2]
    assert tuple(whiskers.get_segments()[0][:, 1]) == pytest.approx((3.9, 4.2))


def test_the_report_writes_and_cleans_every_figure_it_draws() -> None:
    """report.FIGURE_NAMES (written, and removed where stale, without importing matplotlib)
    names report_plots.DRAWN's figures, in their order: a new part's figure in one and not the
    other would never be written, or never cleaned."""
    from aigem.paper import report, report_plots

    assert tuple(report_plots.DRAWN) == report.FIGURE_NAMES
