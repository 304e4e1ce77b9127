"""The numbers of each part of `aigem paper`'s report, from the runs' evaluations on the test
split and the paper's model's metrics logs (aigem.paper.report puts them into report.json):

    table1    AiGem over the seeds beside constant velocity on the same targets, AiGem minus
              constant velocity (paired by seed), and the published rows
    ablation  the RMSE cells of each fit of the d_min or the concatenation ablation, constant
              velocity's, and each fit's difference to the paper's configuration
    curves    each model's train and validation RMSE per epoch over the seeds
    regions   RMSE per horizon by the actor's present position

Every AiGem number is a cell of aigem.paper.report_cells (the mean over the seeds and its interval);
with one seed, where its evaluation has them, the cells of its bootstrap over the test samples.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from aigem.evaluation.results import (
    CONSTANT_VELOCITY_CITATION,
    PAPER_CITATION,
    PAPER_NOTES,
    PAPER_TABLE,
    PUBLISHED_CONSTANT_VELOCITY,
    Evaluation,
    below_fde,
    paper_rows,
)
from aigem.intervals import LEVEL
from aigem.metrics import FRONT_Y_M, REGIONS
from aigem.paper.report_cells import (
    SECONDS,
    TABLE1_KEYS,
    Cell,
    difference_cells,
    seed_cell,
    series_cells,
)
from aigem.runs.run_log import EpochRow

# The published numbers beside the ablations and the regions: the paper gives those as figures
# without numbers, so only its Table 1 row (d_min 25 m, with the concatenation, every actor)
# and constant velocity's published row can stand beside them.
PUBLISHED_AIGEM = "AiGem (paper, Table 1: d_min 25 m, concatenation, all actors)"
PUBLISHED_CV = "constant velocity (CS-LSTM paper, all actors)"
PUBLISHED_SERIES_NOTE = (
    "The paper draws its d_min, concatenation and front / mid / rear results as figures without "
    "numbers; the published rows here are its Table 1 row and the constant-velocity row of "
    f"{CONSTANT_VELOCITY_CITATION}, for scale."
) + (
    " Its AiGem row's RMSE at 5 s lies below its FDE, which its own definitions rule out: see "
    "Table 1's note."
    if "AiGem (paper)" in below_fde()
    else ""
)
BOOTSTRAP_INTERVALS = (
    "percentile bootstrap over the test samples, each sample's actors drawn together; AiGem "
    "minus constant velocity on the same resamples. It measures the test-set noise, not the "
    "training noise, which only more seeds measure"
)
RMSE_KEYS = tuple(f"rmse_{s}s_m" for s in SECONDS)  # RMSE at 1..5 s, evaluate's keys


def rmse_series(
    evaluation: Evaluation, region: str = "all", kind: str = "model"
) -> list[float | None]:
    """RMSE (m) at 1..5 s, each from its own horizon's model (the paper's protocol); `kind`
    "constant_velocity": constant velocity's on the same targets."""
    return [getattr(evaluation, kind)[region].get(f"rmse_{s}s_m") for s in SECONDS]


def rmse_cells(evaluations: Sequence[Evaluation], region: str = "all") -> list[Cell | None]:
    """AiGem's RMSE at 1..5 s over the seeds (one evaluation each): mean and interval."""
    return series_cells([rmse_series(e, region) for e in evaluations])


def constant_velocity_cells(
    evaluations: Sequence[Evaluation], region: str = "all"
) -> list[Cell | None]:
    """Constant velocity's RMSE at 1..5 s on the fit's targets: the first seed's evaluation's
    (it depends on the build alone), cells without bounds."""
    return [
        seed_cell([value]) for value in rmse_series(evaluations[0], region, "constant_velocity")
    ]


def published_series() -> dict[str, list[float]]:
    """The published RMSE at 1..5 s beside the ablations and the regions (PUBLISHED_SERIES_NOTE)."""
    return {
        PUBLISHED_AIGEM: list(PAPER_TABLE["AiGem (paper)"]["rmse_m"]),
        PUBLISHED_CV: list(
            PUBLISHED_CONSTANT_VELOCITY["constant velocity (CS-LSTM paper)"]["rmse_m"]
        ),
    }


def _row(rows: Sequence[dict[str, Any]], parameters: int | None = None) -> dict[str, Any]:
    """Table 1's cells from each seed's row of metrics (one row: no interval)."""
    row: dict[str, Any] = {
        key: seed_cell([values.get(key) for values in rows]) for key in TABLE1_KEYS
    }
    if parameters is not None:
        row["params_k"] = round(parameters / 1000, 1)
    return row


def _paired_cells(evaluation: Evaluation, keys: Sequence[str], kind: str) -> list[Cell | None]:
    """The cells of `keys` from one run's bootstrap intervals (`kind`: a field of
    intervals.Paired: model, constant_velocity or difference, AiGem minus constant velocity on
    the same resamples); None for a key without an interval."""
    found = evaluation.intervals.metrics if evaluation.intervals is not None else {}
    return [None if key not in found else getattr(found[key], kind).as_dict() for key in keys]


def _bootstrap_kind(evaluation: Evaluation) -> dict[str, Any]:
    """What a run's bootstrap intervals are, as report.json's `intervals` of a part says it."""
    found = evaluation.intervals
    assert found is not None
    return {
        "kind": "bootstrap",
        "level": LEVEL,
        "resamples": found.resamples,
        "samples": found.samples,
        "method": BOOTSTRAP_INTERVALS,
    }


def _bootstrap_table1(evaluation: Evaluation) -> dict[str, Any] | None:
    """Table 1's cells of one seed's run from its evaluation's bootstrap intervals (resampled
    test samples, AiGem against constant velocity paired on the same resamples); None where the
    evaluation has none."""
    if evaluation.intervals is None:
        return None

    def cells(kind: str) -> dict[str, Cell | None]:
        return dict(zip(TABLE1_KEYS, _paired_cells(evaluation, TABLE1_KEYS, kind), strict=True))

    aigem = cells("model") | {"params_k": round(evaluation.parameters / 1000, 1)}
    return {
        "ours": {"AiGem (this run)": aigem, "constant velocity": cells("constant_velocity")},
        "aigem_minus_constant_velocity_rmse_m": _paired_cells(evaluation, RMSE_KEYS, "difference"),
        "intervals": _bootstrap_kind(evaluation),
    }


def table1(evaluations: Sequence[Evaluation]) -> dict[str, Any]:
    """Ours (over the seeds) and constant velocity on the same targets, AiGem's RMSE minus
    constant velocity's (paired by seed), beside the paper's rows as published. With one seed,
    the intervals of its evaluation's bootstrap over the test samples (`intervals` says so)."""
    first = evaluations[0]
    cells = {
        "ours": {
            "AiGem (this run)": _row([e.model["all"] for e in evaluations], first.parameters),
            "constant velocity": _row([first.constant_velocity["all"]]),
        },
        "aigem_minus_constant_velocity_rmse_m": difference_cells(
            [rmse_series(e) for e in evaluations],
            [rmse_series(e, kind="constant_velocity") for e in evaluations],
        ),
        "intervals": None,  # the seeds' (report.json's `intervals`)
    }
    if len(evaluations) == 1:
        cells = _bootstrap_table1(first) or cells
    return {
        **cells,
        "targets": [first.model["all"].get(f"n_{s}s") for s in SECONDS],
        "published": {**paper_rows(), **paper_rows(PUBLISHED_CONSTANT_VELOCITY)},
        "published_notes": {**PAPER_NOTES, **below_fde()},
        "published_source": f"{PAPER_CITATION} (NGSIM US-101 and I-80); constant velocity: "
        f"{CONSTANT_VELOCITY_CITATION}",
    }


def _curve(rows: list[EpochRow]) -> dict[str, Any]:
    """One model's curve: its epochs, train and validation RMSE (sqrt of the logged MSE, m)."""
    return {
        "epoch": [row.epoch for row in rows],
        "train_rmse_m": [math.sqrt(row.train_loss_m2) for row in rows],
        "val_rmse_m": [math.sqrt(row.val_loss_m2) for row in rows],
        "best_epoch": rows[-1].best_epoch if rows else None,
    }


def _at(curve: dict[str, Any], key: str, epoch: int | None) -> float | None:
    return curve[key][curve["epoch"].index(epoch)] if epoch in curve["epoch"] else None


def _over_seeds(each: Sequence[dict[str, Any]], key: str, epochs: Sequence[int]) -> list:
    """Per epoch, the cell of `key` over the seeds' curves (`each`) that reached it."""
    return [seed_cell([_at(c, key, e) for c in each if e in c["epoch"]]) for e in epochs]


def curves(
    rows_by_seed: Sequence[dict[str, list[EpochRow]]], seeds: Sequence[int]
) -> dict[str, dict[str, Any]]:
    """Per model (rows_by_seed: each seed's metrics rows by model name): each seed's curve
    (`seeds`), and over them, per epoch, the mean and interval of the seeds that reached it;
    at each seed's best epoch (the model kept), the mean and interval of its RMSE."""
    result = {}
    for name in rows_by_seed[0]:
        each = [_curve(rows[name]) for rows in rows_by_seed]
        epochs = sorted({epoch for curve in each for epoch in curve["epoch"]})
        result[name] = {
            "epoch": epochs,
            "train_rmse_m": _over_seeds(each, "train_rmse_m", epochs),
            "val_rmse_m": _over_seeds(each, "val_rmse_m", epochs),
            "best_epoch": [curve["best_epoch"] for curve in each],
            "at_best": {
                key: seed_cell([_at(c, key, c["best_epoch"]) for c in each])
                for key in ("train_rmse_m", "val_rmse_m")
            },
            "seeds": [{"seed": seed, **curve} for seed, curve in zip(seeds, each, strict=True)],
        }
    return result


def regions(evaluations: Sequence[Evaluation]) -> dict[str, Any]:
    """RMSE at 1..5 s over the seeds, constant velocity's and the targets counted, by the
    actor's present position."""
    return {
        "front_y_m": FRONT_Y_M,
        "rmse_m": {region: rmse_cells(evaluations, region) for region in REGIONS[1:]},
        "constant_velocity_rmse_m": {
            region: constant_velocity_cells(evaluations, region) for region in REGIONS[1:]
        },
        "targets": {
            region: [evaluations[0].model[region].get(f"n_{s}s") for s in SECONDS]
            for region in REGIONS[1:]
        },
    }


def ablation(
    evaluations: dict[str, Sequence[Evaluation]], labelled: dict[str, str], paper: str | None
) -> dict[str, Any]:
    """An ablation's parts: each fit's (`labelled`: label -> fit name) RMSE cells, constant
    velocity's on its targets, and its difference to the `paper` fit (paired by seed). With one
    seed, where its evaluations have them, the cells of each fit's bootstrap over its test
    samples, as Table 1's: AiGem's, constant velocity's and AiGem minus constant velocity's
    (`minus_constant_velocity`, on the same resamples); `intervals` says which (None: the
    seeds')."""
    series = {label: [rmse_series(e) for e in evaluations[n]] for label, n in labelled.items()}
    reference = [rmse_series(e) for e in evaluations[paper]] if paper else None
    parts: dict[str, Any] = {
        "rmse": {label: series_cells(values) for label, values in series.items()},
        "constant_velocity": {
            label: constant_velocity_cells(evaluations[n]) for label, n in labelled.items()
        },
        "difference": {
            label: difference_cells(series[label], reference)
            for label, name in labelled.items()
            if reference is not None and name != paper
        },
        "minus_constant_velocity": {},
        "intervals": None,
    }
    runs = {label: evaluations[name] for label, name in labelled.items()}
    if all(len(each) == 1 and each[0].intervals is not None for each in runs.values()):
        paired = lambda kind: {  # noqa: E731
            label: _paired_cells(each[0], RMSE_KEYS, kind) for label, each in runs.items()
        }
        parts |= {
            "rmse": paired("model"),
            "constant_velocity": paired("constant_velocity"),
            "minus_constant_velocity": paired("difference"),
            "intervals": _bootstrap_kind(next(iter(runs.values()))[0]),
        }
    return parts
