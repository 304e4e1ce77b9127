"""The report of `aigem paper` as one JSON document (report.json), put together from each
part's numbers (aigem.paper.report_parts: the runs' evaluations on the test split and the paper's
model's metrics logs), and its files written: report.json, the same as Markdown (report.md:
aigem.paper.report_text) and the figures (aigem.paper.report_plots). The document's parts:

    table1    AiGem's RMSE at 1..5 s (each from its own horizon's model), ADE and FDE (the 5 s
              model) and parameters; constant velocity on the same targets, and AiGem's RMSE
              minus constant velocity's; the paper's Table 1 and the published NGSIM
              constant-velocity row (Deo and Trivedi 2018)
    dmin      RMSE per horizon of the fits with the output concatenation, by d_min, and each
              one's difference to the paper's d_min 25 m; with one seed each fit's bootstrap
              intervals and its AiGem minus constant velocity (`dmin_minus_constant_velocity`,
              `dmin_intervals`), as Table 1
    concat    RMSE per horizon of the d_min 25 m fits with and without it, and the difference
              (likewise)
    curves    train and validation RMSE per epoch of each horizon's model of the paper's fit
              (the square root of the logged MSE, metres), and why train lies above validation
    regions   RMSE per horizon by the actor's present position (aigem.metrics.region_of)

Each fit is trained once per seed (`--seeds`): every AiGem number is a cell of
aigem.paper.report_cells, the mean over the seeds and its 95 % interval (none with one seed), and each
difference between two settings is taken seed by seed (paired) before its mean and interval.
Constant velocity does not depend on the seed: its numbers are the first seed's evaluation's,
cells without bounds. Every seed's own numbers are kept under `fits` (each run's "test" rows)
and `curves` (each seed's curve). `intervals` says what the intervals are (interval_kind; None:
one seed, no interval), for report.md's words. With one seed a cell has no bounds; an interval
of another kind (a bootstrap over one run's test samples) fits the same cell, report.md shows
and words it alike, and `intervals` is then where its kind is said.

dmin, concat and regions each hold constant velocity on the same targets, and beside them the
published rows (PUBLISHED_SERIES_NOTE: the paper draws these results without numbers); Table 1's
notes say where a published row's RMSE at 5 s lies below its FDE (aigem.evaluation.results.below_fde). The
runs' lines say each model's "trained N of M" epochs, and how to continue an unfinished fit.

Where the builds are of synthetic data every table and figure says SYNTHETIC, where some of
their inputs are PARTLY SYNTHETIC; where --max-hours left a run unfinished, UNFINISHED (and
report.json's "finished" is false). The time each stage took is kept apart, under `timings` in
report.json and the last section of report.md, so that two calls on the same inputs give the
same report but for it.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from aigem.evaluation.results import Evaluation
from aigem.intervals import LEVEL
from aigem.paper.report_parts import (
    PUBLISHED_SERIES_NOTE,
    ablation,
    curves,
    published_series,
    regions,
    table1,
)
from aigem.paper.report_text import report_markdown
from aigem.paper_layout import PAPER_D_MIN_M
from aigem.runs.run_log import EpochRow
from ngsim_graphs.partial_files import write_atomic
from ngsim_graphs.synth.marker import SYNTHETIC_LABEL

PARTLY_SYNTHETIC_LABEL = (
    "the inputs' recordings, PARTLY SYNTHETIC: some of them written by `ngsim-graphs synth` "
    "(each build's manifest names them: synthetic_inputs)"
)
FIGURE_NAMES = ("table1", "dmin", "concat", "curves", "regions")  # report_plots.DRAWN's (tested)
SEED_INTERVALS = (
    "Student's t over the seeds, N - 1 degrees of freedom: an interval so made holds the mean "
    "over many more seeds 95 times in 100"
)
# A fit's settings and its runs, one per seed: seed, run (its folder's name), models (courses).
Fit = dict[str, Any]


def _data_words(synthetic: bool, partly_synthetic: bool) -> str:
    if synthetic:
        return SYNTHETIC_LABEL
    return PARTLY_SYNTHETIC_LABEL if partly_synthetic else "the inputs' recordings"


def interval_kind(seeds: Sequence[int]) -> dict[str, Any] | None:
    """What the report's intervals are (report.json's `intervals`), None with one seed."""
    if len(seeds) < 2:
        return None
    return {"kind": "seeds", "level": LEVEL, "seeds": len(seeds), "method": SEED_INTERVALS}


def _fits(
    fits: dict[str, Fit], evaluations: dict[str, Sequence[Evaluation]]
) -> dict[str, dict[str, Any]]:
    """Each fit's settings and test samples, its runs with each seed's numbers (`test`: its
    metric rows by region), constant velocity's rows once."""
    return {
        name: {
            "d_min_m": fit["d_min_m"],
            "concat_position": fit["concat_position"],
            "test_samples": evaluations[name][0].samples,
            "parameters": evaluations[name][0].parameters,
            "runs": [
                {**run, "test": evaluation.model}
                for run, evaluation in zip(fit["runs"], evaluations[name], strict=True)
            ],
            "constant_velocity_test": evaluations[name][0].constant_velocity,
        }
        for name, fit in fits.items()
    }


def paper_report(
    settings: dict[str, Any],
    parts: Sequence[str],
    seeds: Sequence[int],
    fits: dict[str, Fit],
    evaluations: dict[str, Sequence[Evaluation]],
    curve_rows: Sequence[dict[str, list[EpochRow]]],
    unfinished: Sequence[str] = (),
    partly_synthetic: bool = False,
) -> dict[str, Any]:
    """report.json's numbers (its figures and timings are added by write_report). `fits` and
    `evaluations` by fit name, each fit's runs and evaluations in the order of `seeds`; the
    paper's fit is the one of d_min 25 m with the output concatenation; `curve_rows`: its
    models' metrics rows by model name, one dict per seed; `unfinished`: the runs that
    --max-hours stopped before their last epoch ("finished" false, and every table and figure
    says UNFINISHED); `partly_synthetic`: some inputs, not all, are synth's (every table and
    figure says PARTLY SYNTHETIC)."""
    synthetic = any(e.synthetic for runs in evaluations.values() for e in runs)
    by_setting = {(f["d_min_m"], f["concat_position"]): name for name, f in fits.items()}
    paper_fit = by_setting.get((PAPER_D_MIN_M, True))
    document: dict[str, Any] = {
        "written_by": "aigem paper",
        "finished": not unfinished,
        "unfinished_fits": list(unfinished),
        "synthetic": synthetic,
        "partly_synthetic": partly_synthetic and not synthetic,
        "data": _data_words(synthetic, partly_synthetic),
        "split": "test",
        "parts": list(parts),
        "settings": {"inputs": settings["inputs"], **settings["config"]},
        "seeds": list(seeds),
        "intervals": interval_kind(seeds),
        "fits": _fits(fits, evaluations),
    }
    if "table" in parts and paper_fit is not None:
        document["table1"] = table1(evaluations[paper_fit])
    if "dmin" in parts:
        with_concat = sorted((d, n) for (d, concat), n in by_setting.items() if concat)
        labelled = {f"{d:g}": name for d, name in with_concat}
        document |= _prefixed("dmin", ablation(evaluations, labelled, paper_fit))
    if "concat" in parts:
        paper_setting = sorted(
            (item for item in by_setting.items() if item[0][0] == PAPER_D_MIN_M), reverse=True
        )
        labelled = {("with" if c else "without"): name for (_, c), name in paper_setting}
        document |= _prefixed("concat", ablation(evaluations, labelled, paper_fit))
    if {"dmin", "concat", "regions"} & set(parts):
        document["published_rmse_m"] = published_series()
        document["published_rmse_note"] = PUBLISHED_SERIES_NOTE
    if "curves" in parts and curve_rows:
        document["curves"] = curves(curve_rows, seeds)
    if "regions" in parts and paper_fit is not None:
        document["regions"] = regions(evaluations[paper_fit])
    return document


def _prefixed(key: str, parts: dict[str, Any]) -> dict[str, Any]:
    """An ablation's parts under report.json's keys: KEY (the RMSE cells), KEY_constant_velocity,
    KEY_difference (to the paper's configuration), KEY_minus_constant_velocity (each fit's AiGem
    minus constant velocity: with one seed, the bootstrap's) and KEY_intervals (None: the
    seeds')."""
    return {
        key: parts["rmse"],
        f"{key}_constant_velocity": parts["constant_velocity"],
        f"{key}_difference": parts["difference"],
        f"{key}_minus_constant_velocity": parts["minus_constant_velocity"],
        f"{key}_intervals": parts["intervals"],
    }


def write_report(
    out: Path, document: dict[str, Any], figures: dict[str, bytes], timings: dict[str, float]
) -> dict[str, Any]:
    """The figures (name -> PNG, `aigem.paper.report_plots.report_figures` of the document) into
    out/figures (those of earlier calls that this one does not draw go), report.md, and
    report.json last of all: its presence says the call finished. Each file is written aside and
    renamed. Returns report.json's document."""
    folder = out / "figures"
    folder.mkdir(exist_ok=True)
    for name in FIGURE_NAMES:
        path = folder / f"{name}.png"
        if name in figures:
            write_atomic(path, figures[name])
        elif path.is_file() and not path.is_symlink():
            path.unlink()
    document = {**document, "figures": [f"figures/{name}.png" for name in figures]}
    write_atomic(out / "report.md", report_markdown(document, timings).encode())
    finished = {**document, "timings": timings}
    write_atomic(out / "report.json", (json.dumps(finished, indent=2) + "\n").encode())
    return finished
