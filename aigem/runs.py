"""The run directory of `aigem fit`: every path in it, checkpoints, the log and the curves.

    RUN/run.json        what was trained on what: the build (absolute path, config hash, sha256
                        of its manifest.json, config, fitted scaler), the model and train configs
    RUN/metrics.jsonl   one line per epoch: train and validation loss (metres^2), best so far
    RUN/last.pt         model, optimizer and progress after the last finished epoch (resume)
    RUN/best.pt         the model of the epoch with the lowest validation loss
    RUN/baseline.json   constant velocity's validation loss, in the definition of the log's
                        val_loss_m2 (aigem.baseline): the line a model has to get below
    RUN/curves.png      training and validation loss per epoch, the best epoch, the baseline

Every checkpoint carries run.json's content as its `info`, so a checkpoint alone says which build
it belongs to and how its inputs are scaled (aigem.checkpoints reads and checks them). run.json
also records each checkpoint's sha256 (records.DIGESTS), which loading checks. Before a
checkpoint is replaced, run.json is rewritten to accept its present bytes and its new ones, and
after, the new ones alone: a kill at any point leaves checkpoints whose bytes run.json accepts,
and a resume settles the record on the bytes it finds.

A multi-horizon run (`aigem fit --horizon-s 1,2,3,4,5`, the paper's protocol) holds one such run
directory per horizon and a file naming them:

    RUN/horizons.json   {"horizons_s": [1.0, 2.0, ...], "members": ["h1s", "h2s", ...]}
    RUN/h1s/, RUN/h2s/  each what a single-horizon fit of that horizon writes

Files are written to a fresh partial file `.NAME.partial-HEX`, created exclusively and never
through a link, and renamed (ngsim_graphs.partial_files): a kill never leaves a torn file, a link
put in the run is never written through, and a failed write (a full disk) removes its partial file
and is one error naming the file. The log is appended to, never through a link.

A fresh fit writes only into a new or empty folder, or into one that a fit left before its first
checkpoint: such a folder carries fit's marker `RUN/.fit-started` (aigem.unfinished), written
before anything else and removed once the first last.pt is kept, and nothing else but a run's
files. A folder that only looks like a run (run.json and best.pt kept without last.pt, a copy)
is refused, never emptied; `--resume` continues a run whose last.pt is its own.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import torch
from torch import nn

from aigem.checkpoints import (
    ALTERED,
    BEST_KEYS,
    LAST_KEYS,
    check_weights,
    checkpoint_sha256,
    fitted_model,
    load_checkpoint,
)
from aigem.config import ModelConfig, TrainConfig
from aigem.course import course_of
from aigem.model import AiGem
from aigem.records import (  # noqa: F401  (the run directory's names, here too)
    BASELINE,
    BEST,
    CURVES,
    DIGESTS,
    FIT_LOG,
    HORIZONS,
    IDENTITY,
    LAST,
    METRICS,
    RUN_FILES,
    RUN_INFO,
    STARTED,
    STARTED_LINE,
    Group,
    accepted_digests,
    member_dir,
    model_config,
    read_baseline,
    read_horizons,
    read_metrics,
    read_run_info,
    recorded_digests,
    run_info,
)
from aigem.refusals import (
    check_fresh_group,
    check_fresh_out,
    check_group_start,
    check_member_start,
    check_resume,
)
from aigem.unfinished import mark_started, unfinished_group, unfinished_start, unmark_started
from ngsim_graphs.errors import NgsimInputError, NgsimOutputError
from ngsim_graphs.integrity import file_sha256
from ngsim_graphs.partial_files import leftover_partials, write_atomic, write_failure


@dataclass(frozen=True)
class RunState:
    next_epoch: int = 0
    best_epoch: int = -1
    best_val_loss: float = math.inf


# ------------------------------------------------------------------------------------------------
# Reading: a run directory, its run.json and its best model.


def _check_same_run(checkpoint_info: dict[str, Any], run: dict[str, Any], path: Path) -> None:
    """A checkpoint from another run (another build, model or horizon) is not this run's. The
    model configs are compared as read (aigem.records.model_config): a best.pt kept before a
    resume rewrote run.json may lack settings that run.json names at their defaults."""
    for key in IDENTITY:
        if checkpoint_info[key] != run[key]:
            raise NgsimInputError(
                path, f"belongs to another run: its {key} differs from {RUN_INFO}'s"
            )
    if model_config(checkpoint_info, path) != model_config(run, path.parent / RUN_INFO):
        raise NgsimInputError(path, f"belongs to another run: its model differs from {RUN_INFO}'s")
    if checkpoint_info["train"].get("horizon_s") != run["train"].get("horizon_s"):
        raise NgsimInputError(
            path, f"belongs to another run: its horizon differs from {RUN_INFO}'s"
        )


def load_model(
    run_dir: str | os.PathLike[str], device: torch.device | str = "cpu"
) -> tuple[AiGem, dict[str, Any]]:
    """The best model of a run and its run info (the checkpoint's)."""
    run_dir = Path(run_dir)
    run = read_run_info(run_dir)
    path = run_dir / BEST
    if not path.is_file():
        raise NgsimInputError(run_dir, f"not a finished run: no {BEST} (no epoch has finished yet)")
    checkpoint = load_checkpoint(path, BEST_KEYS, accepted_digests(run, run_dir, BEST))
    _check_same_run(checkpoint["info"], run, path)
    if (run_dir / LAST).is_file():  # a run kept without it has no other record of its epochs
        check_log(run_dir, epochs_kept(run_dir))
    model = fitted_model(checkpoint["info"], checkpoint["model"], path)
    return model.to(device).eval(), checkpoint["info"]


# ------------------------------------------------------------------------------------------------
# Writing: atomically, never a torn file, never through a link (write_atomic: partial_files).


def _serialised(payload: dict[str, Any]) -> bytes:
    buffer = io.BytesIO()  # serialised in memory, so that every disk error is Python's OSError
    torch.save(payload, buffer)
    return buffer.getvalue()


def _append_line(path: Path, text: str) -> None:
    """Append one line to a log, never through a link; a failed write leaves the log as it was
    (no torn line)."""
    flags = os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC
    try:
        fd = os.open(path, flags, 0o666)
    except OSError as err:
        raise write_failure(path, err) from None
    try:
        size, data = os.fstat(fd).st_size, (text + "\n").encode()
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


def _write_info(run_dir: Path, info: dict[str, Any], digests: dict[str, list[str]]) -> None:
    """run.json: the run `info` and the sha256 values each checkpoint may have (DIGESTS)."""
    text = json.dumps({**info, DIGESTS: digests}, indent=2) + "\n"
    write_atomic(run_dir / RUN_INFO, text.encode())


def _settled_digests(run_dir: Path) -> dict[str, list[str]]:
    """run.json's record of the checkpoints as a resume finds them: each one's own sha256, which
    must be one that run.json accepts (a kill while fit replaced it leaves two); a run written
    before they were recorded has its checkpoints' taken as they are (unchecked: the CLI
    warns)."""
    run = read_run_info(run_dir)
    recorded = recorded_digests(run, run_dir / RUN_INFO)
    settled = {}
    for name in (BEST, LAST):
        path = run_dir / name
        if not path.is_file():
            continue
        digest = file_sha256(path)
        if recorded is not None and digest not in (accepted_digests(run, run_dir, name) or ()):
            raise NgsimInputError(path, ALTERED)
        settled[name] = [digest]
    return settled


# ------------------------------------------------------------------------------------------------
# A run's course: start (or resume), one checkpoint per epoch.


def start_run(
    run_dir: Path,
    build_dir: Path,
    model_config: ModelConfig,
    train: TrainConfig,
    resume: bool,
    model: nn.Module,
    optimizer: torch.optim.Optimizer,
    is_writer: bool,
) -> tuple[RunState, dict[str, Any]]:
    """Start a fresh run, or load the last checkpoint into `model` and `optimizer` to resume;
    returns the state and the run info that every checkpoint of this run carries. A directory
    with last.pt needs `resume`; one without it has nothing to resume and starts over."""
    check_member_start(run_dir, resume)
    info = run_info(build_dir, model_config, train)
    if resume:
        state = _resume(run_dir, build_dir, info, model, optimizer)
        if is_writer:
            _remove_leftovers(run_dir)  # the run is ours: its last.pt is
            unmark_started(run_dir)  # killed after its first last.pt, before this
            # the latest limits (epochs, time, patience); best.pt checked too
            _write_info(run_dir, info, _settled_digests(run_dir))
            _drop_metrics_after(run_dir, state.next_epoch)
        return state, info
    if is_writer:  # the other ranks of a distributed run would see rank 0 writing run.json
        _start_over(run_dir, info)
    return RunState(), info


def _start_over(run_dir: Path, info: dict[str, Any]) -> None:
    """Set up `run_dir` for a fresh run: new or empty, or what a fit left before its first
    checkpoint (check_fresh_out), whose files then go: nothing to resume, so its log rows,
    best.pt, baseline.json and partial files go, and the run starts over. Fit's marker is
    written first, so that a kill at any point leaves a folder the next fit takes."""
    check_fresh_out(run_dir)
    created = not run_dir.exists()
    run_dir.mkdir(parents=True, exist_ok=True)
    try:
        mark_started(run_dir)
        _remove_leftovers(run_dir)
        for name in (METRICS, BEST, BASELINE, CURVES):
            (run_dir / name).unlink(missing_ok=True)
        _write_info(run_dir, info, {})
    except NgsimOutputError:
        if created:
            unmark_started(run_dir)
            with contextlib.suppress(OSError):
                run_dir.rmdir()
        raise


def _remove_leftovers(folder: Path) -> None:
    """Remove the partial files of a run's files that a killed fit left in `folder` (ours)."""
    for path in leftover_partials(folder, RUN_FILES):
        path.unlink(missing_ok=True)


def start_group(group: Group, resume: bool, is_writer: bool) -> None:
    """Check a run directory for a fresh start or a resume of `group`, whose members `start_run`
    then starts one by one; a fresh group of several writes its horizons.json. A resume needs the
    same horizons and a last.pt in at least one member (a member without one, killed before its
    first checkpoint, starts over)."""
    run_dir = group.run_dir
    check_group_start(group, resume)
    if not is_writer or not group.named:  # a group of one is its member's folder: start_run's
        return
    if resume:
        _remove_leftovers(run_dir)
        unmark_started(run_dir)  # a member has kept a checkpoint
        return
    check_fresh_group(group)
    run_dir.mkdir(parents=True, exist_ok=True)
    mark_started(run_dir)
    _remove_leftovers(run_dir)
    names = [member.name for member in group.members]
    text = json.dumps({"horizons_s": list(group.horizons_s), "members": names}, indent=2) + "\n"
    write_atomic(run_dir / HORIZONS, text.encode())


def _resume(
    run_dir: Path,
    build_dir: Path,
    info: dict[str, Any],
    model: nn.Module,
    optimizer: torch.optim.Optimizer,
) -> RunState:
    last = run_dir / LAST
    if not last.is_file():
        raise NgsimInputError(run_dir, f"nothing to resume: no {LAST}")
    run = read_run_info(run_dir)
    checkpoint = load_checkpoint(last, LAST_KEYS, accepted_digests(run, run_dir, LAST))
    saved = checkpoint["info"]
    _check_same_run(saved, run, last)
    check_resume(run_dir, build_dir, saved, info)
    check_weights(model.state_dict(), checkpoint["model"], last)
    state = _run_state(checkpoint["state"], last)
    check_log(run_dir, state.next_epoch)
    model.load_state_dict(checkpoint["model"])
    _load_optimizer(optimizer, checkpoint["optimizer"], last)
    return state


def _load_optimizer(optimizer: torch.optim.Optimizer, saved: object, path: Path) -> None:
    """Load an optimizer state of the same kind (Adam's hyper-parameters, one group per group)."""
    expected = optimizer.state_dict()["param_groups"]
    groups = saved.get("param_groups") if isinstance(saved, dict) else None
    if (
        not isinstance(groups, list)
        or len(groups) != len(expected)
        or any(
            not isinstance(g, dict) or set(g) != set(e)
            for g, e in zip(groups, expected, strict=True)
        )
    ):
        raise NgsimInputError(path, "its optimizer state is not this run's optimizer's (Adam)")
    try:
        optimizer.load_state_dict(saved)  # type: ignore[arg-type]
    except (KeyError, TypeError, ValueError, RuntimeError) as err:
        reason = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise NgsimInputError(
            path, f"its optimizer state does not fit the model: {reason}"
        ) from None


def _run_state(saved: object, path: Path) -> RunState:
    names = [f.name for f in fields(RunState)]
    number = lambda v: isinstance(v, int | float) and not isinstance(v, bool)
    if (
        not isinstance(saved, dict)
        or sorted(saved) != sorted(names)
        or not all(map(number, saved.values()))
    ):
        raise NgsimInputError(
            path, f"its progress record is not aigem's (expected {', '.join(names)})"
        )
    return RunState(
        next_epoch=int(saved["next_epoch"]),
        best_epoch=int(saved["best_epoch"]),
        best_val_loss=float(saved["best_val_loss"]),
    )


def end_epoch(
    run_dir: Path,
    state: RunState,
    info: dict[str, Any],
    epoch: int,
    train_loss: float,
    val_loss: float,
    model: nn.Module,
    optimizer: torch.optim.Optimizer,
    is_writer: bool,
    timing: dict[str, float] | None = None,
) -> tuple[RunState, dict[str, float]]:
    """Log the epoch (with `timing`, e.g. seconds and graphs/s), keep the best model, and
    checkpoint with the run's `info`; returns the new state and the metrics row."""
    better = math.isfinite(val_loss) and val_loss < state.best_val_loss
    new = RunState(
        next_epoch=epoch + 1,
        best_epoch=epoch if better else state.best_epoch,
        best_val_loss=val_loss if better else state.best_val_loss,
    )
    row = {
        "epoch": epoch + 1,
        "train_loss_m2": train_loss,
        "val_loss_m2": val_loss,
        "best_epoch": new.best_epoch + 1,
        **(timing or {}),
    }
    if not is_writer:
        return new, row
    kept = {}
    if better:
        kept[BEST] = _serialised({"info": info, "model": model.state_dict(), "epoch": epoch})
    last = {
        "info": info,
        "model": model.state_dict(),
        "optimizer": optimizer.state_dict(),
        "state": asdict(new),
    }
    kept[LAST] = _serialised(last)
    # run.json accepts each checkpoint's present bytes and its new ones while it is replaced,
    # then the new ones alone: a kill at any point leaves checkpoints that load.
    digests = recorded_digests(read_run_info(run_dir), run_dir / RUN_INFO) or {}
    new_digests = {name: checkpoint_sha256(data) for name, data in kept.items()}
    replacing = {name: [*digests.get(name, []), d] for name, d in new_digests.items()}
    _write_info(run_dir, info, {**digests, **replacing})
    if BEST in kept:
        write_atomic(run_dir / BEST, kept[BEST])
    _append_line(run_dir / METRICS, json.dumps(row))
    write_atomic(run_dir / LAST, kept[LAST])
    _write_info(run_dir, info, {**digests, **{name: [d] for name, d in new_digests.items()}})
    unmark_started(run_dir)  # a checkpoint is kept: a fresh fit may no longer start over here
    return new, row


def _drop_metrics_after(run_dir: Path, epochs_done: int) -> None:
    """Forget logged epochs after the last checkpoint's: a run stopped between writing an epoch's
    row and its last.pt redoes that epoch, which must not be logged twice."""
    rows = read_metrics(run_dir)
    kept = [row for row in rows if row["epoch"] <= epochs_done]
    if len(kept) < len(rows) or (run_dir / METRICS).is_symlink():  # a link: replaced, not followed
        write_atomic(run_dir / METRICS, "".join(json.dumps(row) + "\n" for row in kept).encode())


def plot_curves(run_dir: Path, synthetic: bool = False) -> Path | None:
    """Training and validation loss per epoch, the best epoch and constant velocity's validation
    loss as a PNG (aigem.plots), titled with how many of its epochs the run trained
    (aigem.course), marked SYNTHETIC where the run's build is of synthetic data;
    None before the first epoch."""
    from aigem.plots import curves_png  # matplotlib (a second to import), only when drawing

    rows = read_metrics(run_dir)
    if not rows:
        return None
    horizon_s = read_run_info(run_dir)["train"].get("horizon_s")
    course = course_of(run_dir)
    trained = course.words() + ("" if course.finished else " (UNFINISHED: continue with --resume)")
    picture = curves_png(rows, read_baseline(run_dir), horizon_s, synthetic, trained)
    write_atomic(run_dir / CURVES, picture)
    return run_dir / CURVES


# ------------------------------------------------------------------------------------------------
# After an interruption: what a run kept.


def epochs_kept(run_dir: Path) -> int:
    """The epochs whose checkpoint a run directory holds (its last.pt's), 0 without one."""
    path = run_dir / LAST
    if not path.is_file():
        return 0
    accepted = accepted_digests(read_run_info(run_dir), run_dir, LAST)
    return _run_state(load_checkpoint(path, LAST_KEYS, accepted)["state"], path).next_epoch


def check_log(run_dir: Path, kept: int) -> None:
    """Refuse a run whose metrics.jsonl disagrees with its last.pt, which holds `kept` epochs:
    the log holds epochs 1, 2, ... in order, up to last.pt's or one more (a fit stopped between
    logging an epoch and keeping its last.pt; a resume redoes that epoch). A log that lost its
    last line would have evaluate call the run unfinished while it scores a later model, and a
    resume leave a hole in it."""
    logged = [row["epoch"] for row in read_metrics(run_dir)]
    in_order = logged == list(range(1, len(logged) + 1))
    if in_order and kept <= len(logged) <= kept + 1:
        return
    if not logged:
        said = "logs no epoch"
    elif in_order:
        said = f"ends at epoch {logged[-1]}"
    else:
        said = f"logs epochs {', '.join(map(str, logged))}, not 1 to {max(logged)} in order,"
    raise NgsimInputError(
        run_dir,
        f"its {METRICS} {said} but its {LAST} holds epoch {kept}: the log lost lines or was "
        f"edited; put back the {METRICS} this run wrote, or fit a new run into another --out",
    )


def check_logs(group: Group) -> None:
    """check_log for each model of `group` that holds a last.pt (before a resume writes)."""
    for member in group.members:
        if (member / LAST).is_file():
            check_log(member, epochs_kept(member))


def discard_unfinished(group: Group, created: bool) -> None:
    """Remove what a fit of `group` that finished no epoch wrote: each member's files, the member
    directories left empty, horizons.json, and the run directory itself where the fit `created`
    it and it is left empty. Only a folder that is, beyond doubt, what a fit left before its first
    checkpoint (unfinished.unfinished_start, unfinished_group) is touched: files of these names in
    any other folder stay."""
    run_dir = group.run_dir
    for member in group.members:
        if not unfinished_start(member):
            continue
        _remove_leftovers(member)
        for name in (RUN_INFO, BASELINE, METRICS, CURVES, BEST, FIT_LOG):
            (member / name).unlink(missing_ok=True)
        unmark_started(member)
        if member != run_dir and not any(member.iterdir()):
            member.rmdir()
    if group.named and unfinished_group(run_dir, group.horizons_s):  # a group of several
        _remove_leftovers(run_dir)
        for name in (HORIZONS, FIT_LOG):
            (run_dir / name).unlink(missing_ok=True)
        unmark_started(run_dir)
    if created and run_dir.is_dir() and not any(run_dir.iterdir()):
        run_dir.rmdir()
