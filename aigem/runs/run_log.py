"""A run's log, read and written without PyTorch: metrics.jsonl, one row per epoch (EpochRow),
and baseline.json, constant velocity's validation loss (aigem.runs.baseline measures it). This is the
one module that reads their keys (aigem.runs.records reads run.json's).

The log is appended to, a line per epoch, never through a link; a failed write leaves it as it
was (no torn line). A row that an older aigem wrote lacks the settings logged since (the epoch's
times from d6f6ee0 on, its learning rate from 7031b38 on): they read as None.
"""

from __future__ import annotations

import contextlib
import json
import os
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from aigem.runs.records import BASELINE, METRICS
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.partial_files import write_atomic, write_failure


@dataclass(frozen=True)
class EpochRow:
    """A row of metrics.jsonl: an epoch's losses (MSE, metres²) and how it went. Epochs are
    counted from 1; `best_epoch` is the one of the lowest validation loss so far."""

    epoch: int
    train_loss_m2: float
    val_loss_m2: float
    best_epoch: int
    train_graphs: int | None = None  # fewer than the split's where the time limit cut the epoch
    train_seconds: float | None = None
    train_graphs_per_s: float | None = None
    val_seconds: float | None = None
    learning_rate: float | None = None  # its last step's

    def to_json(self) -> dict[str, Any]:
        """The row as metrics.jsonl holds it: its fields in order, those it lacks left out."""
        values = ((f.name, getattr(self, f.name)) for f in fields(self))
        return {name: value for name, value in values if value is not None}


REQUIRED = tuple(f.name for f in fields(EpochRow) if f.default is not None)


def _row(value: object) -> EpochRow | None:
    """A logged row as an EpochRow; None for one that is not aigem's (damaged)."""
    if not isinstance(value, dict) or not all(key in value for key in REQUIRED):
        return None
    known = {f.name: value[f.name] for f in fields(EpochRow) if value.get(f.name) is not None}
    number = lambda v: isinstance(v, int | float) and not isinstance(v, bool)
    if not all(map(number, known.values())) or not all(
        isinstance(known[key], int) for key in ("epoch", "best_epoch")
    ):
        return None  # a row logs numbers, its epochs whole ones (ignoring keys it does not know)
    return EpochRow(**known)


def _logged(run_dir: Path) -> list[tuple[EpochRow, str]]:
    """Each row of metrics.jsonl with its line; one line naming the file and line where it is
    damaged."""
    path = run_dir / METRICS
    if not path.exists():
        return []
    rows = []
    for number, line in enumerate(path.read_text(errors="replace").splitlines(), start=1):
        if not line.strip():
            continue
        try:
            row = _row(json.loads(line))
        except json.JSONDecodeError:
            row = None
        if row is None:
            raise NgsimInputError(path, "not a row of aigem's metrics log (damaged?)", line=number)
        rows.append((row, line))
    return rows


def read_metrics(run_dir: Path) -> list[EpochRow]:
    """The rows of metrics.jsonl; one line naming the file and line where it is damaged."""
    return [row for row, _ in _logged(run_dir)]


def append_row(run_dir: Path, row: EpochRow) -> None:
    """Append `row` to the log, never through a link; a failed write leaves the log as it was
    (no torn line)."""
    path = run_dir / METRICS
    flags = os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC
    try:
        fd = os.open(path, flags, 0o666)
    except OSError as err:
        raise write_failure(path, err) from None
    try:
        size, data = os.fstat(fd).st_size, (json.dumps(row.to_json()) + "\n").encode()
        try:
            done = 0
            while done < len(data):
                done += os.write(fd, data[done:])
        except OSError as err:
            with contextlib.suppress(OSError):
                os.ftruncate(fd, size)
            raise write_failure(path, err) from None
    finally:
        os.close(fd)


def drop_rows_after(run_dir: Path, epochs_done: int) -> None:
    """Forget logged epochs after the last checkpoint's: a run stopped between writing an epoch's
    row and its last.pt redoes that epoch, which must not be logged twice. The rows kept keep
    their lines as written; a log that is a link is replaced, not followed."""
    logged = _logged(run_dir)
    kept = [line for row, line in logged if row.epoch <= epochs_done]
    if len(kept) < len(logged) or (run_dir / METRICS).is_symlink():
        write_atomic(run_dir / METRICS, "".join(line + "\n" for line in kept).encode())


def write_baseline(run_dir: Path, val_loss_m2: float, steps: int) -> None:
    """Record constant velocity's validation loss (metres^2) over `steps` future steps."""
    text = json.dumps({"constant_velocity_val_loss_m2": val_loss_m2, "steps": steps}) + "\n"
    write_atomic(run_dir / BASELINE, text.encode())


def read_baseline(run_dir: Path) -> float | None:
    """Constant velocity's validation loss (metres^2) as fit recorded it; None when the run has
    none (a run of an older aigem) or it is unreadable: a missing baseline only costs the line."""
    try:
        value = json.loads((run_dir / BASELINE).read_text())["constant_velocity_val_loss_m2"]
    except (OSError, ValueError, TypeError, KeyError):
        return None
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None
