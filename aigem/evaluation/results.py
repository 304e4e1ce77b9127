"""What `aigem evaluate` finds, as data: a run's scores on one split as the paper reports them
(Evaluation: a run is a group of one model per horizon, each scored as a ModelEvaluation), their
JSON form, and the paper's table beside which they are read. aigem.evaluation.evaluate computes them;
aigem.figures.plots draws them; the CLI prints them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from aigem.intervals import SampleIntervals
from aigem.metrics import ErrorTotals, SampleTotals

# The paper's Table 1 (NGSIM US-101 + I-80, metres), every row as published, in its order; for
# comparison only. None: not reported.
PAPER_TABLE = {
    "CS-LSTM (paper)": {
        "ade_m": 2.29,
        "fde_m": 3.34,
        "rmse_m": (0.61, 1.27, 2.09, 3.10, 4.37),
        "params_k": 192,
    },
    "GRIP++ (paper)": {
        "ade_m": 1.61,
        "fde_m": None,
        "rmse_m": (0.38, 0.89, 1.45, 2.14, 2.94),
        "params_k": 496,
    },
    "STA-LSTM (paper)": {
        "ade_m": 1.89,
        "fde_m": 3.16,
        "rmse_m": (0.37, 0.98, 1.71, 2.63, 3.78),
        "params_k": 125,
    },
    "DeepTrack (paper)": {
        "ade_m": 2.01,
        "fde_m": 3.25,
        "rmse_m": (0.47, 1.08, 1.83, 2.75, 3.89),
        "params_k": 109,
    },
    "GSTCN (paper)": {
        "ade_m": 1.52,
        "fde_m": None,
        "rmse_m": (0.44, 0.83, 1.33, 2.01, 2.98),
        "params_k": 49.8,
    },
    "AiGem (paper)": {
        "ade_m": 1.42,
        "fde_m": 2.57,
        "rmse_m": (0.61, 1.02, 1.27, 1.84, 1.95),
        "params_k": 74.5,
    },
}
# The paper's footnotes to its table, by row.
PAPER_NOTES = {
    "GRIP++ (paper)": "parameters not reported by GRIP++'s authors; the AiGem paper extracted "
    "the number from their shared code",
}


def below_fde(table: dict[str, dict[str, Any]] = PAPER_TABLE) -> dict[str, str]:
    """Per published row whose RMSE at 5 s lies below its FDE (at 5 s too), why its numbers
    cannot be of one set of predictions scored by the paper's own definitions: at one step the
    RMSE, the root of the mean squared Euclidean distance, is at least the mean distance (the
    quadratic mean is never below the arithmetic one), and the FDE is that mean at 5 s."""
    notes = {}
    for name, row in table.items():
        fde, rmse = row["fde_m"], row["rmse_m"][-1]
        if fde is not None and rmse < fde:
            notes[name] = (
                f"its RMSE at 5 s ({rmse:.2f} m) lies below its FDE ({fde:.2f} m), which the "
                "paper's own definitions rule out for one set of predictions: at a step the RMSE "
                "(the root of the mean squared distance) is at least the mean distance, the FDE "
                "at 5 s; so its RMSE cannot be the Euclidean one of the predictions its FDE "
                "scores (its formula writes no norm: an RMSE per coordinate, the Euclidean one over "
                f"√2, would fit, {rmse:.2f} × √2 = {rmse * math.sqrt(2):.2f} m ≥ {fde:.2f} m; "
                "the paper does not say which)"
            )
    return notes


PAPER_CITATION = (
    "Samiuddin, Boulet, Wu: Trajectory Prediction for Autonomous Driving using Agent-Interaction "
    "Graph Embedding, arXiv:2410.23298, Table 1"
)

# Constant velocity on NGSIM US-101 + I-80, as published beside Table 1's CS-LSTM row (pooled
# RMSE at 1..5 s, metres; no ADE, FDE or parameters): the line a model has to get below there.
PUBLISHED_CONSTANT_VELOCITY = {
    "constant velocity (CS-LSTM paper)": {
        "ade_m": None,
        "fde_m": None,
        "rmse_m": (0.73, 1.78, 3.13, 4.78, 6.68),
        "params_k": None,
    }
}
CONSTANT_VELOCITY_CITATION = (
    "Deo, Trivedi: Convolutional Social Pooling for Vehicle Trajectory Prediction, CVPR "
    "Workshops 2018, Table 1, the constant-velocity row (NGSIM US-101 and I-80)"
)


def paper_rows(table: dict[str, dict[str, Any]] = PAPER_TABLE) -> dict[str, dict[str, Any]]:
    """PAPER_TABLE (or another published `table`) in the keys of evaluate's rows: its RMSE as
    rmse_1s_m .. rmse_5s_m."""
    return {
        name: {
            **{key: value for key, value in row.items() if key != "rmse_m"},
            **{f"rmse_{s}s_m": value for s, value in enumerate(row["rmse_m"], start=1)},
        }
        for name, row in table.items()
    }


@dataclass(frozen=True)
class FinalErrors:
    """The final displacement error (metres) of each target valid at the last predicted step, of
    the model and of constant velocity, and the target's sample (its index in the split)."""

    sample: np.ndarray  # (T,) int64
    model_m: np.ndarray  # (T,) float64
    constant_velocity_m: np.ndarray  # (T,) float64


@dataclass(frozen=True)
class Scores:
    """What `score_targets` accumulates over a split (metres): per region, the final errors,
    and per sample (all regions; what the bootstrap resamples)."""

    model: ErrorTotals
    constant_velocity: ErrorTotals
    final: FinalErrors
    model_by_sample: SampleTotals
    constant_velocity_by_sample: SampleTotals


@dataclass(frozen=True)
class ModelEvaluation:
    """One model of a run (a member) on one split."""

    split: str
    horizon_steps: int
    samples: int
    parameters: int  # of the model
    model: dict[str, dict[str, float | None]]
    constant_velocity: dict[str, dict[str, float | None]]
    build_dir: str
    same_build: bool  # False: another build than the run's (--other-build), scaled as the run's
    synthetic: bool  # the build is of `ngsim-graphs synth`'s data (ngsim_graphs.synth.marker)
    time_step_s: float
    protocol: str  # the build's protocol (BuildConfig.protocol): which samples were scored
    protocol_description: str  # describe_protocol of the build
    # "model" / "constant_velocity" -> region -> rmse_m, mean_error_m, n: a list of K (None
    # where no target counts), at future steps 1..K (metrics.step_errors)
    steps: dict[str, dict[str, dict[str, list]]]
    # what the run's records say of its training (aigem.runs.course.training_record): "trained 1 of 3
    # epochs", finished or not, how to continue
    training: dict[str, Any] | None = None
    # the bootstrap's 95 % intervals of the metrics over all actors (aigem.intervals); None
    # where evaluate was asked for none (--bootstrap 0)
    intervals: SampleIntervals | None = None
    final: FinalErrors | None = field(default=None, repr=False, compare=False)  # not in --json


Rows = dict[str, dict[str, float | None]]  # region -> metric -> metres (or a count)


@dataclass(frozen=True)
class Evaluation:
    """A run on one split, as the paper reports it: RMSE at h s from the first model that reaches
    h s, ADE and FDE from the longest-horizon model (aigem.evaluation.evaluate.protocol_rows); a run of
    one model is a group of one, whose rows are its model's. `sources` names the member each
    metric comes from, `members` holds each member's own evaluation (ascending by horizon)."""

    split: str
    horizons_s: tuple[float, ...]
    samples: int
    parameters: int  # of each model
    model: Rows
    constant_velocity: Rows
    sources: dict[str, str]  # metric -> member (its run directory's name)
    members: dict[str, ModelEvaluation]
    build_dir: str
    same_build: bool
    synthetic: bool
    protocol: str  # the build's protocol (BuildConfig.protocol): which samples were scored
    protocol_description: str  # describe_protocol of the build
    training: dict[str, Any] | None = None  # of every member (aigem.runs.course.training_record)
    # the 95 % intervals of the metrics over all actors, each from the member its row comes
    # from (aigem.intervals.SampleIntervals.combined); None with --bootstrap 0
    intervals: SampleIntervals | None = None

    @property
    def longest(self) -> ModelEvaluation:
        """The longest-horizon model's evaluation: the one whose steps, final errors and scenes
        are drawn."""
        return list(self.members.values())[-1]

    # The longest model's per-step errors, final errors and grid (not in --json: in its member).
    steps = property(lambda self: self.longest.steps)
    final = property(lambda self: self.longest.final)
    horizon_steps = property(lambda self: self.longest.horizon_steps)
    time_step_s = property(lambda self: self.longest.time_step_s)


def as_dict(result: Evaluation) -> dict[str, Any]:
    """One JSON-ready document: the run's rows, the longest model's horizon (horizon_steps of
    time_step_s), each member's evaluation (its per-step errors among them) and the paper's
    table."""
    document = _public(result)
    document["horizon_steps"], document["time_step_s"] = result.horizon_steps, result.time_step_s
    document["members"] = {name: _public(m) for name, m in result.members.items()}
    return {**document, "paper": PAPER_TABLE}


def _public(result: Evaluation | ModelEvaluation) -> dict[str, Any]:
    """The fields of --json: all but the per-target final errors (arrays, for pictures); the
    intervals as SampleIntervals.as_dict writes them."""
    document = {key: value for key, value in result.__dict__.items() if key != "final"}
    if result.intervals is not None:
        document["intervals"] = result.intervals.as_dict()
    return document
