"""Frozen configuration dataclasses of the model and of training. Field names carry units. And
the one mapping from their fields to `aigem fit`'s options (`fit_option`), which the CLI's
messages and the command that continues a run (aigem.runs.course.resume_command) both read."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields
from enum import Enum
from typing import Any

from ngsim_graphs.config import (
    DEFAULT_EDGE_TYPES,
    MAX_PARALLEL,
    BuildConfig,
    check_above,
    check_at_least,
    check_count,
    check_seed,
    whole_steps,
)

MAX_HORIZON_S = 5.0  # the builds' 25 future steps at 0.2 s
TIME_STEP_S = BuildConfig.time_step_s  # the grid of the builds `ngsim-graphs build` makes, s
MIN_HORIZON_S = TIME_STEP_S  # one step of that grid: a model predicts at least one step


def horizon_steps(horizon_s: float, time_step_s: float = TIME_STEP_S) -> int:
    """The future steps a horizon of `horizon_s` s predicts and scores on a grid of `time_step_s`
    s (5 per second at 0.2 s). ValueError for a horizon of less than one step (a build on a
    coarser grid may make a short horizon one) or of no whole number of steps (0.3 s at 0.2 s:
    a model of 1 step, 0.2 s, would be reported as 0.3 s)."""
    steps = horizon_s / time_step_s
    if not steps > 1 - 1e-9:  # NaN too
        raise ValueError(
            f"a {horizon_s:g} s horizon is less than one time step ({time_step_s:g} s)"
        )
    if not whole_steps(horizon_s, time_step_s):
        raise ValueError(
            f"a {horizon_s:g} s horizon is not a whole number of time steps ({time_step_s:g} s)"
        )
    return round(steps)


class LrSchedule(str, Enum):
    """How the learning rate runs over the epochs (aigem.training.schedule)."""

    CONSTANT = "constant"  # the paper's
    COSINE = "cosine"  # falls to 0 along half a cosine by the end of `epochs`


class DeviceChoice(str, Enum):
    """Where a model runs: `auto` takes CUDA when present (aigem.devices.pick_device)."""

    AUTO = "auto"
    CPU = "cpu"
    CUDA = "cuda"


LR_SCHEDULES = tuple(schedule.value for schedule in LrSchedule)


@dataclass(frozen=True)
class ModelConfig:
    """AiGem's shape (docs/aigem.md). The default has 74,242 parameters (the paper: 74.5 K)."""

    node_features: int = 4  # [x, y, heading, speed]
    hidden: int = 64  # encoder and GRU width
    layers: int = 4  # L: GAT + linear encoder layers
    heads: int = 1  # GAT attention heads (outputs averaged, so the width stays `hidden`)
    mlp_hidden: int = 128
    dropout: float = 0.05
    concat_position: bool = True  # the output MLP sees the previous position (ablation: False)
    # Beyond the paper: each step's displacement is constant velocity's plus the MLP's output.
    cv_residual: bool = False
    future_steps: int = 25  # K_F predicted steps (5 s at 0.2 s)
    # A GAT per edge type of the build, in its order: fit sets them from the build's config
    # (BuildConfig.edge_types); a run that records none has the paper's two.
    edge_types: tuple[str, ...] = DEFAULT_EDGE_TYPES

    def __post_init__(self) -> None:
        for name in ("node_features", "hidden", "layers", "heads", "mlp_hidden", "future_steps"):
            check_count(name, getattr(self, name), 1)
        check_at_least("dropout", self.dropout, 0)
        if not self.dropout < 1:
            raise ValueError(f"dropout must be below 1, not {self.dropout:g}")

    @property
    def history_steps_read(self) -> int:
        """History steps that reach the present-step embeddings: temporal edges join consecutive
        steps, so L layers read the present and the L steps before it."""
        return self.layers + 1

    def to_dict(self) -> dict[str, Any]:
        """The settings as run.json records them (JSON's form: the edge types a list)."""
        return {**asdict(self), "edge_types": list(self.edge_types)}


@dataclass(frozen=True)
class TrainConfig:
    """How `aigem fit` trains."""

    horizon_s: float = 5.0  # the paper trains one model per horizon, 1..5 s
    epochs: int = 100
    batch_size: int = 32  # samples (graphs) per batch
    learning_rate: float = 1e-3  # Adam's, after the warm-up (aigem.training.schedule)
    lr_schedule: str = "constant"  # or "cosine": decay to 0 by the end of `epochs`
    warmup_epochs: float = 0.0  # linear warm-up of the learning rate
    clip_grad_norm: float | None = None  # clip the gradients' total L2 norm to this
    max_minutes: float | None = None  # stop after this much training time
    patience_epochs: int | None = None  # early stop without a better validation loss
    seed: int = 0
    workers: int | None = None  # DataLoader worker processes (None: aigem.cores.default_workers)
    threads: int | None = None  # intra-op CPU threads (None: the idle usable cores, aigem.cores)
    compile: bool | None = None  # the decoder through torch.compile (None: on CUDA, eager steps)
    # The splits on the device, static batches, captured steps (aigem.training.engine); None: on CUDA,
    # where the splits fit its free memory; False: the DataLoader's batches.
    resident: bool | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.horizon_s) and 0 < self.horizon_s <= MAX_HORIZON_S):
            raise ValueError("horizon_s must be in (0, 5]")
        if self.horizon_s < MIN_HORIZON_S:
            raise ValueError(f"horizon_s must be at least one time step ({MIN_HORIZON_S:g} s)")
        if not whole_steps(self.horizon_s, TIME_STEP_S):
            raise ValueError(f"horizon_s must be a multiple of the {TIME_STEP_S:g} s time step")
        check_count("epochs", self.epochs, 1)
        check_count("batch_size", self.batch_size, 1)
        check_above("learning_rate", self.learning_rate, 0)
        if self.lr_schedule not in LR_SCHEDULES:
            raise ValueError(f"lr_schedule must be one of {', '.join(LR_SCHEDULES)}")
        check_at_least("warmup_epochs", self.warmup_epochs, 0)
        if not self.warmup_epochs < self.epochs:
            raise ValueError("warmup_epochs must be >= 0 and fewer than epochs")
        if self.clip_grad_norm is not None:
            check_above("clip_grad_norm", self.clip_grad_norm, 0)
        if self.max_minutes is not None:
            check_above("max_minutes", self.max_minutes, 0)
        check_seed("seed", self.seed)
        if self.patience_epochs is not None:
            check_count("patience_epochs", self.patience_epochs, 1)
        if self.workers is not None:
            check_count("workers", self.workers, 0, MAX_PARALLEL)
        if self.threads is not None:
            check_count("threads", self.threads, 1, MAX_PARALLEL)

    def compiles_on(self, device_type: str) -> bool:
        """Whether the decoder is compiled on this device: `compile`, else on CUDA only (there it
        saves ~2,000 kernel launches a step; on the CPU compiling costs a minute and the step is
        no faster)."""
        return self.compile if self.compile is not None else device_type == "cuda"

    def resident_on(self, device_type: str) -> bool:
        """Whether a fit on this device asks for its splits on the device (`resident`, else on
        CUDA only: there a step of the loader's batches waits on ~2,000 kernel launches; on
        the CPU the loader's batches with their CSR plans are as fast, bench/bench_train.py)."""
        return self.resident if self.resident is not None else device_type == "cuda"

    def horizon_steps(self, time_step_s: float) -> int:
        """Future steps predicted and scored on a grid of `time_step_s` s (horizon_steps)."""
        return horizon_steps(self.horizon_s, time_step_s)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def check_horizons_s(horizons_s: Sequence[float]) -> tuple[float, ...]:
    """Horizons of a multi-horizon fit, ascending: at least one, each in (0, 5] s and a whole
    number of time steps (0.2 s), none twice."""
    if not horizons_s:
        raise ValueError("no horizon given")
    for horizon_s in horizons_s:
        if not (math.isfinite(horizon_s) and 0 < horizon_s <= MAX_HORIZON_S):
            raise ValueError(f"{horizon_s:g} s is not a horizon in (0, {MAX_HORIZON_S:g}] s")
        if horizon_s < MIN_HORIZON_S:
            raise ValueError(f"{horizon_s:g} s is shorter than one time step ({MIN_HORIZON_S:g} s)")
        horizon_steps(horizon_s)  # a whole number of the builds' steps
    names = [
        f"{h:g}" for h in horizons_s
    ]  # as a run names its members (aigem.runs.records.member_dir)
    twice = sorted({name for name in names if names.count(name) > 1}, key=float)
    if twice:
        raise ValueError(f"{', '.join(twice)} s given more than once")
    return tuple(sorted(float(h) for h in horizons_s))


def parse_horizons_s(text: str) -> tuple[float, ...]:
    """'1,2,3,4,5' -> (1.0, 2.0, 3.0, 4.0, 5.0); '5' -> (5.0,). ValueError in one line."""
    values = []
    for part in text.split(","):
        try:
            values.append(float(part))
        except ValueError:
            raise ValueError(f"{part.strip()!r} is not a number of seconds") from None
    return check_horizons_s(values)


# ------------------------------------------------------------------------------------------------
# `aigem fit`'s options of the configs' fields. A field's option is `--` and its name with hyphens
# (batch_size: --batch-size), a bool's `--name` and `--no-name` (as typer makes them), but for the
# fields of OPTIONS: another name, a bool's flag for each value (a value without one is its
# default, set by no flag), or None where no option sets the field (the model's shape, set from
# Python; its edge types, the build's). A new field is named here only where its option differs.

OPTIONS: dict[str, str | dict[bool, str] | None] = {
    "patience_epochs": "--patience",
    "resident": {True: "--resident", False: "--loader"},
    "concat_position": {False: "--no-concat"},
    "cv_residual": {True: "--cv-residual"},
    **dict.fromkeys(
        ("node_features", "hidden", "layers", "heads", "mlp_hidden", "dropout", "future_steps",
         "edge_types"),
    ),
}  # fmt: skip
# The train settings a resumed run may change: how far and how it trains, not what it learns
# (every other field of TrainConfig, a new one too, must stay: aigem.runs.refusals.RESUME_FIXED).
RESUMABLE = frozenset(
    {"epochs", "max_minutes", "patience_epochs", "workers", "threads", "compile", "resident"}
)


def _flags(name: str) -> dict[bool | None, str] | None:
    """A field's options by the value they give: a bool's flags by True and False, an option
    that takes a value by None; None where no option sets the field."""
    option = OPTIONS.get(name, "--" + name.replace("_", "-"))
    if option is None or isinstance(option, dict):
        return option
    return {True: option, False: "--no-" + option[2:], None: option}


def fit_option(name: str, value: object) -> list[str]:
    """The words of `aigem fit` that set field `name` of TrainConfig or ModelConfig to `value`:
    ["--batch-size", "16"], ["--learning-rate", "0.003"], ["--no-concat"]; [] where no option
    sets it (OPTIONS), for None, and for a bool's value that no flag gives."""
    flags = _flags(name)
    if flags is None or value is None:
        return []
    if isinstance(value, bool):
        return [flags[value]] if value in flags else []
    return [flags[None], f"{value:g}" if isinstance(value, float) else str(value)]


def option_words() -> dict[str, str]:
    """How a message names the option of each field of TrainConfig and ModelConfig that one
    sets ("batch_size" -> "--batch-size", "concat_position" -> "--no-concat")."""
    named = {f.name: _flags(f.name) for c in (TrainConfig, ModelConfig) for f in fields(c)}
    return {name: next(iter(flags.values())) for name, flags in named.items() if flags}
