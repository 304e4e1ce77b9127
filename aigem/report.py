"""The report of `aigem paper`: its numbers as one JSON document (report.json), the same as
Markdown (report.md), and the figures (aigem.report_plots), from the fits' evaluations on the
test split and the paper's model's metrics logs.

    table1    AiGem's RMSE at 1..5 s (each from its own horizon's model), ADE and FDE (the 5 s
              model) and parameters; constant velocity on the same targets; the paper's Table 1
              and the published NGSIM constant-velocity row (Deo and Trivedi 2018)
    dmin      RMSE per horizon of the fits with the output concatenation, by d_min
    concat    RMSE per horizon of the d_min 25 m fits with and without it
    curves    train and validation RMSE per epoch of each horizon's model of the paper's fit
              (the square root of the logged MSE, metres), and why train lies above validation
    regions   RMSE per horizon by the actor's present position (aigem.metrics.region_of)

dmin, concat and regions each hold constant velocity on the same targets, and beside them the
published rows (PUBLISHED_SERIES_NOTE: the paper draws these results without numbers). The runs'
lines say each model's "trained N of M" epochs, and how to continue an unfinished fit.

Where the builds are of synthetic data every table and figure says SYNTHETIC, where some of
their inputs are PARTLY SYNTHETIC; where --max-hours left a fit unfinished, UNFINISHED (and
report.json's "finished" is false). The time each stage took is kept apart, under `timings` in
report.json and the last section of report.md, so that two calls on the same inputs give the
same report but for it.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from aigem.metrics import FRONT_Y_M, REGIONS
from aigem.paper_folder import HORIZONS_S, PAPER_D_MIN_M
from aigem.results import (
    CONSTANT_VELOCITY_CITATION,
    PAPER_CITATION,
    PAPER_NOTES,
    PAPER_TABLE,
    PUBLISHED_CONSTANT_VELOCITY,
    Evaluation,
    paper_rows,
)
from ngsim_graphs.partial_files import write_atomic
from ngsim_graphs.synth.marker import SYNTHETIC_LABEL

SECONDS = tuple(round(h) for h in HORIZONS_S)  # 1..5: the keys' rmse_{s}s_m
PARTLY_SYNTHETIC_LABEL = (
    "the inputs' recordings, PARTLY SYNTHETIC: some of them written by `ngsim-graphs synth` "
    "(each build's manifest names them: synthetic_inputs)"
)
UNFINISHED = "UNFINISHED: training stopped by --max-hours; run the same command again to continue"
TIME_HEADING = "## Time taken"  # report.md's last section: the only one that differs between calls
FIGURE_NAMES = ("table1", "dmin", "concat", "curves", "regions")
# Why a train curve may lie above the validation one (ModelConfig.dropout is 0.05).
TRAIN_ABOVE_VALIDATION = (
    "The train RMSE can lie above the validation RMSE: it is the mean over the epoch's batches, "
    "with the model's 5 % dropout active and the weights still changing, while validation scores "
    "the epoch's final model with dropout off."
)
# The published numbers beside the ablations and the regions: the paper gives those as figures
# without numbers, so only its Table 1 row (d_min 25 m, with the concatenation, every actor)
# and constant velocity's published row can stand beside them.
PUBLISHED_AIGEM = "AiGem (paper, Table 1: d_min 25 m, concatenation, all actors)"
PUBLISHED_CV = "constant velocity (CS-LSTM paper, all actors)"
PUBLISHED_SERIES_NOTE = (
    "The paper draws its d_min, concatenation and front / mid / rear results as figures without "
    "numbers; the published rows here are its Table 1 row and the constant-velocity row of "
    f"{CONSTANT_VELOCITY_CITATION}, for scale."
)
Fit = dict[str, Any]  # d_min_m, concat_position, models (each model's course)


def rmse_series(
    evaluation: Evaluation, region: str = "all", kind: str = "model"
) -> list[float | None]:
    """RMSE (m) at 1..5 s, each from its own horizon's model (the paper's protocol); `kind`
    "constant_velocity": constant velocity's on the same targets."""
    return [getattr(evaluation, kind)[region].get(f"rmse_{s}s_m") for s in SECONDS]


def published_series() -> dict[str, list[float]]:
    """The published RMSE at 1..5 s beside the ablations and the regions (PUBLISHED_SERIES_NOTE)."""
    return {
        PUBLISHED_AIGEM: list(PAPER_TABLE["AiGem (paper)"]["rmse_m"]),
        PUBLISHED_CV: list(
            PUBLISHED_CONSTANT_VELOCITY["constant velocity (CS-LSTM paper)"]["rmse_m"]
        ),
    }


def _row(values: dict[str, Any], parameters: int | None = None) -> dict[str, Any]:
    row = {key: values.get(key) for key in ("ade_m", "fde_m")}
    row.update({f"rmse_{s}s_m": values.get(f"rmse_{s}s_m") for s in SECONDS})
    if parameters is not None:
        row["params_k"] = round(parameters / 1000, 1)
    return row


def table1(evaluation: Evaluation) -> dict[str, Any]:
    """Ours and constant velocity on the same targets, beside the paper's rows as published."""
    return {
        "ours": {
            "AiGem (this run)": _row(evaluation.model["all"], evaluation.parameters),
            "constant velocity": _row(evaluation.constant_velocity["all"]),
        },
        "targets": [evaluation.model["all"].get(f"n_{s}s") for s in SECONDS],
        "published": {**paper_rows(), **paper_rows(PUBLISHED_CONSTANT_VELOCITY)},
        "published_notes": PAPER_NOTES,
        "published_source": f"{PAPER_CITATION} (NGSIM US-101 and I-80); constant velocity: "
        f"{CONSTANT_VELOCITY_CITATION}",
    }


def curves(rows_by_model: dict[str, list[dict[str, Any]]]) -> dict[str, dict[str, list]]:
    """Per model: its epochs, train and validation RMSE (sqrt of the logged MSE, m)."""
    return {
        name: {
            "epoch": [int(row["epoch"]) for row in rows],
            "train_rmse_m": [math.sqrt(row["train_loss_m2"]) for row in rows],
            "val_rmse_m": [math.sqrt(row["val_loss_m2"]) for row in rows],
            "best_epoch": int(rows[-1]["best_epoch"]) if rows else None,
        }
        for name, rows in rows_by_model.items()
    }


def regions(evaluation: Evaluation) -> dict[str, Any]:
    """RMSE at 1..5 s and the targets counted, by the actor's present position."""
    return {
        "front_y_m": FRONT_Y_M,
        "rmse_m": {region: rmse_series(evaluation, region) for region in REGIONS[1:]},
        "constant_velocity_rmse_m": {
            region: rmse_series(evaluation, region, "constant_velocity") for region in REGIONS[1:]
        },
        "targets": {
            region: [evaluation.model[region].get(f"n_{s}s") for s in SECONDS]
            for region in REGIONS[1:]
        },
    }


def _data_words(synthetic: bool, partly_synthetic: bool) -> str:
    if synthetic:
        return SYNTHETIC_LABEL
    return PARTLY_SYNTHETIC_LABEL if partly_synthetic else "the inputs' recordings"


def paper_report(
    settings: dict[str, Any],
    parts: Sequence[str],
    fits: dict[str, Fit],
    evaluations: dict[str, Evaluation],
    curve_rows: dict[str, list[dict[str, Any]]],
    unfinished: Sequence[str] = (),
    partly_synthetic: bool = False,
) -> dict[str, Any]:
    """report.json's numbers (its figures and timings are added by write_report). `fits` and
    `evaluations` by run name; the paper's fit is the one of d_min 25 m with the output
    concatenation; `curve_rows`: its models' metrics rows, by model name; `unfinished`: the
    fits that --max-hours stopped before their last epoch ("finished" false, and every table
    and figure says UNFINISHED); `partly_synthetic`: some inputs, not all, are synth's (every
    table and figure says PARTLY SYNTHETIC)."""
    synthetic = any(e.synthetic for e in evaluations.values())
    by_setting = {(f["d_min_m"], f["concat_position"]): name for name, f in fits.items()}
    paper = evaluations.get(by_setting.get((PAPER_D_MIN_M, True), ""))
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
        "fits": {
            name: {
                **fit,
                "test_samples": evaluations[name].samples,
                "parameters": evaluations[name].parameters,
            }
            for name, fit in fits.items()
        },
    }
    if "table" in parts and paper is not None:
        document["table1"] = table1(paper)
    if "dmin" in parts:
        with_concat = sorted((d, n) for (d, concat), n in by_setting.items() if concat)
        document["dmin"] = {f"{d:g}": rmse_series(evaluations[n]) for d, n in with_concat}
        document["dmin_constant_velocity"] = {
            f"{d:g}": rmse_series(evaluations[n], kind="constant_velocity") for d, n in with_concat
        }
    if "concat" in parts:
        paper_setting = sorted(
            (item for item in by_setting.items() if item[0][0] == PAPER_D_MIN_M), reverse=True
        )
        document["concat"] = {
            ("with" if concat else "without"): rmse_series(evaluations[name])
            for (_, concat), name in paper_setting
        }
        document["concat_constant_velocity"] = {
            ("with" if concat else "without"): rmse_series(
                evaluations[name], kind="constant_velocity"
            )
            for (_, concat), name in paper_setting
        }
    if {"dmin", "concat", "regions"} & set(parts):
        document["published_rmse_m"] = published_series()
        document["published_rmse_note"] = PUBLISHED_SERIES_NOTE
    if "curves" in parts:
        document["curves"] = curves(curve_rows)
    if "regions" in parts and paper is not None:
        document["regions"] = regions(paper)
    return document


# ------------------------------------------------------------------------------------------------
# report.md


def _counted(count: int, noun: str) -> str:
    return f"{count:,} {noun}{'' if count == 1 else 's'}"


def _m(value: float | None) -> str:
    return "–" if value is None else f"{value:.2f}"


def _count(value: int | None) -> str:
    return "–" if value is None else f"{value:,}"


def _table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return lines + ["| " + " | ".join(row) + " |" for row in rows]


def _rmse_header(first: str) -> list[str]:
    return [first, *(f"RMSE {s} s (m)" for s in SECONDS)]


def data_mark(document: dict[str, Any]) -> str | None:
    """What the report says of its data: SYNTHETIC, PARTLY SYNTHETIC, or nothing (None)."""
    if document["synthetic"]:
        return "SYNTHETIC"
    return "PARTLY SYNTHETIC" if document["partly_synthetic"] else None


def _mark(document: dict[str, Any]) -> str:
    """What a heading says of the whole report: (PARTLY) SYNTHETIC data, UNFINISHED training."""
    marks = [data_mark(document)] + ["UNFINISHED"] * (not document["finished"])
    shown = [mark for mark in marks if mark]
    return f" ({', '.join(shown)})" if shown else ""


def _table1_lines(document: dict[str, Any]) -> list[str]:
    part = document["table1"]
    header = ["model", "ADE (m)", "FDE (m)", *(f"RMSE {s} s (m)" for s in SECONDS), "params (K)"]
    header.append("numbers")
    mark = data_mark(document)
    ours = "this call" + (f", {mark} data" if mark else "")
    rows = []
    for source, table in ((ours, part["ours"]), ("published, NGSIM", part["published"])):
        for name, row in table.items():
            params = row.get("params_k")
            rows.append(
                [
                    name,
                    _m(row["ade_m"]),
                    _m(row["fde_m"]),
                    *(_m(row[f"rmse_{s}s_m"]) for s in SECONDS),
                    "–" if params is None else f"{params:g}",
                    source,
                ]
            )
    notes = [f"- {name}: {note}." for name, note in part["published_notes"].items()]
    return [
        f"## Table 1: AiGem beside constant velocity and the published models{_mark(document)}",
        "",
        *_table(header, rows),
        "",
        "AiGem's RMSE at h s comes from the model trained for h s, its ADE and FDE from the 5 s "
        "model (the paper's protocol); constant velocity is scored on the same targets. Targets "
        "at 1..5 s: " + ", ".join(_count(n) for n in part["targets"]) + ".",
        f"Published rows: {part['published_source']}.",
        *notes,
        "",
        "![Table 1 as a figure](figures/table1.png)",
        "",
    ]


def _published_rows(document: dict[str, Any], extra: int = 0) -> list[list[str]]:
    """The published rows beside an ablation or the regions (`extra` empty cells after them)."""
    return [
        [f"{name}, published NGSIM", *map(_m, values), *["–"] * extra]
        for name, values in document["published_rmse_m"].items()
    ]


def _series_lines(
    document: dict[str, Any], key: str, title: str, first: str, name: str
) -> list[str]:
    """An ablation's AiGem rows, constant velocity on each fit's targets, the published rows."""
    rows = [[label, *map(_m, values)] for label, values in document[key].items()]
    rows += [
        [f"{label}: constant velocity, same targets", *map(_m, values)]
        for label, values in document[f"{key}_constant_velocity"].items()
    ]
    return [
        f"## {title}{_mark(document)}",
        "",
        *_table(_rmse_header(first), rows + _published_rows(document)),
        "",
        document["published_rmse_note"],
        "",
        f"![{title}](figures/{name}.png)",
        "",
    ]


def _curves_lines(document: dict[str, Any]) -> list[str]:
    rows = []
    for name, curve in document["curves"].items():
        best = curve["best_epoch"]
        at = curve["epoch"].index(best) if best in curve["epoch"] else None
        rows.append(
            [
                name,
                str(len(curve["epoch"])),
                "–" if best is None else str(best),
                "–" if at is None else _m(curve["train_rmse_m"][at]),
                "–" if at is None else _m(curve["val_rmse_m"][at]),
            ]
        )
    header = ["model", "epochs", "best epoch", "train RMSE (m)", "validation RMSE (m)"]
    return [
        f"## Training curves of the paper's model (d_min 25 m){_mark(document)}",
        "",
        *_table(header, rows),
        "",
        "RMSE here is the square root of the logged MSE over the valid future steps; the best "
        "epoch (lowest validation loss) is the model kept. " + TRAIN_ABOVE_VALIDATION,
        "",
        "![Training curves](figures/curves.png)",
        "",
    ]


def _regions_lines(document: dict[str, Any]) -> list[str]:
    part = document["regions"]
    y = f"{part['front_y_m']:g}"
    words = {
        "front": f"front (y > {y} m)",
        "mid": f"mid (-{y} m ≤ y ≤ {y} m)",
        "rear": f"rear (y < -{y} m)",
    }
    rows = [
        [words[region], *map(_m, values), _count(part["targets"][region][-1])]
        for region, values in part["rmse_m"].items()
    ]
    rows += [
        [
            f"{words[region]}: constant velocity",
            *map(_m, values),
            _count(part["targets"][region][-1]),
        ]
        for region, values in part["constant_velocity_rmse_m"].items()
    ]
    return [
        f"## Front / mid / rear: RMSE by the actor's present position{_mark(document)}",
        "",
        *_table([*_rmse_header("region"), "targets at 5 s"], rows + _published_rows(document, 1)),
        "",
        document["published_rmse_note"],
        "",
        "![RMSE by region](figures/regions.png)",
        "",
    ]


def _courses(models: dict[str, dict[str, Any]], epochs: int) -> str:
    """Each model's 'trained N of M epochs' and best epoch, why they stopped (once where alike),
    and where the time limit stopped one, how to continue."""
    stops = {m["stopped"] for m in models.values()}
    each = "; ".join(
        f"{name}: trained {m['epochs_done']} of {epochs} (best {m['best_epoch']}"
        + ("" if len(stops) == 1 else f", {m['stopped']}")
        + ")"
        for name, m in models.items()
    )
    line = f"{each}; stopped by {next(iter(stops))}" if len(stops) == 1 else each
    if "time limit" in stops:
        line += "; UNFINISHED: the same `aigem paper` command continues it"
    return line


def _fits_lines(document: dict[str, Any]) -> list[str]:
    rows = [
        [
            name,
            f"{fit['d_min_m']:g}",
            "yes" if fit["concat_position"] else "no",
            f"{fit['test_samples']:,}",
            _courses(fit["models"], document["settings"]["epochs"]),
        ]
        for name, fit in document["fits"].items()
    ]
    header = ["run", "d_min (m)", "concatenation", "test samples", "epochs of each model"]
    return ["## Runs", "", *_table(header, rows), ""]


def report_markdown(document: dict[str, Any], timings: dict[str, float]) -> str:
    """report.md: the report's tables, its figures, and the time each stage took (last)."""
    settings = document["settings"]
    patience = settings["patience_epochs"]
    size = sum(f["size_bytes"] for f in settings["inputs"])
    lines = [
        f"# AiGem: the paper's experiments{_mark(document)}",
        "",
        (
            f"**{data_mark(document)}**: every number of this call comes from "
            f"{document['data']}; only the rows marked published are NGSIM results."
            if data_mark(document)
            else f"Every number of this call comes from {document['data']}."
        ),
        "",
        f"Inputs: {_counted(len(settings['inputs']), 'file')}, {size:,} bytes. Training: up to "
        f"{_counted(settings['epochs'], 'epoch')}, batch {settings['batch_size']}, seed {settings['seed']}, "
        f"patience {'none' if patience is None else patience}. Scored on the "
        f"{document['split']} split.",
        "",
    ]
    if not document["finished"]:
        fits = ", ".join(document["unfinished_fits"])
        lines[2:2] = [f"**{UNFINISHED}** (unfinished fits: {fits}).", ""]
    if "table1" in document:
        lines += _table1_lines(document)
    if "dmin" in document:
        lines += _series_lines(document, "dmin", "d_min ablation", "d_min (m)", "dmin")
    if "concat" in document:
        title = "Output concatenation ablation (d_min 25 m)"
        lines += _series_lines(document, "concat", title, "previous position at the MLP", "concat")
    if "curves" in document:
        lines += _curves_lines(document)
    if "regions" in document:
        lines += _regions_lines(document)
    lines += _fits_lines(document)
    lines += [TIME_HEADING, "", *(f"- {stage}: {s:,.1f} s" for stage, s in timings.items()), ""]
    return "\n".join(lines)


def write_report(
    out: Path, document: dict[str, Any], figures: dict[str, bytes], timings: dict[str, float]
) -> dict[str, Any]:
    """The figures (name -> PNG, `aigem.report_plots.report_figures` of the document) into
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
