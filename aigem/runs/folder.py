"""The course of `aigem fit` in its run directory: a fresh start or a resume, a checkpoint and a
log row per epoch, the curves, and what a fit that kept nothing leaves (aigem.runs.records and
aigem.runs.run_log write the files' contents, aigem.runs.checkpoints the checkpoints' and reads them back).

    RUN/run.json        what was trained on what: the build (absolute path, config hash, sha256
                        of its manifest.json, config, fitted scaler), the model and train configs
    RUN/metrics.jsonl   one line per epoch: train and validation loss (metres^2), best so far
    RUN/last.pt         model, optimizer and progress after the last finished epoch (resume)
    RUN/best.pt         the model of the epoch with the lowest validation loss
    RUN/baseline.json   constant velocity's validation loss, in the definition of the log's
                        val_loss_m2 (aigem.runs.baseline): the line a model has to get below
    RUN/curves.png      training and validation loss per epoch, the best epoch, the baseline

Every checkpoint carries run.json's content as its `info`, so a checkpoint alone says which build
it belongs to and how its inputs are scaled (aigem.runs.checkpoints). run.json also records each
checkpoint's sha256 (records.DIGESTS), which loading checks. Before a checkpoint is replaced,
run.json is rewritten to accept its present bytes and its new ones, and after, the new ones alone:
a kill at any point leaves checkpoints whose bytes run.json accepts, and a resume settles the
record on the bytes it finds.

A multi-horizon run (`aigem fit --horizon-s 1,2,3,4,5`, the paper's protocol) holds one such run
directory per horizon and a file naming them:

    RUN/horizons.json   {"horizons_s": [1.0, 2.0, ...], "members": ["h1s", "h2s", ...]}
    RUN/h1s/, RUN/h2s/  each what a single-horizon fit of that horizon writes

Files are written to a fresh partial file `.NAME.partial-HEX`, created exclusively and never
through a link, and renamed (ngsim_graphs.partial_files): a kill never leaves a torn file, a link
put in the run is never written through, and a failed write (a full disk) removes its partial file
and is one error naming the file. The log is appended to, never through a link.

A fresh fit writes only into a new or empty folder, or into one that a fit left before its first
checkpoint: such a folder carries fit's marker `RUN/.fit-started` (aigem.runs.unfinished), written
before anything else and removed once the first last.pt is kept, and nothing else but a run's
files. A folder that only looks like a run (run.json and best.pt kept without last.pt, a copy)
is refused, never emptied; `--resume` continues a run whose last.pt is its own.
"""

from __future__ import annotations

import contextlib
import math
from pathlib import Path

import torch
from torch import nn

from aigem.config import ModelConfig, TrainConfig
from aigem.runs.checkpoints import (
    ALTERED,
    LAST_KEYS,
    best_bytes,
    check_log,
    check_same_run,
    check_weights,
    checkpoint_sha256,
    last_bytes,
    load_checkpoint,
)
from aigem.runs.course import course_of
from aigem.runs.records import (  # noqa: F401  (the run directory's names, here too)
    BASELINE,
    BEST,
    CURVES,
    DIGESTS,
    FIT_LOG,
    HORIZONS,
    LAST,
    METRICS,
    RUN_FILES,
    RUN_INFO,
    STARTED,
    STARTED_LINE,
    Group,
    RunInfo,
    RunState,
    accepted_digests,
    read_record,
    run_info,
    write_horizons,
    write_record,
)
from aigem.runs.refusals import (
    check_fresh_group,
    check_fresh_out,
    check_group_start,
    check_member_start,
    check_resume,
)
from aigem.runs.run_log import EpochRow, append_row, drop_rows_after, read_baseline, read_metrics
from aigem.runs.unfinished import mark_started, unfinished_group, unfinished_start, unmark_started
from ngsim_graphs.errors import NgsimInputError, NgsimOutputError
from ngsim_graphs.integrity import file_sha256
from ngsim_graphs.partial_files import leftover_partials, write_atomic


def _settled_digests(run_dir: Path) -> dict[str, tuple[str, ...]]:
    """run.json's record of the checkpoints as a resume finds them: each one's own sha256, which
    must be one that run.json accepts (a kill while fit replaced it leaves two); a run written
    before they were recorded has its checkpoints' taken as they are (unchecked: the CLI
    warns)."""
    run = read_record(run_dir)
    settled = {}
    for name in (BEST, LAST):
        path = run_dir / name
        if not path.is_file():
            continue
        digest = file_sha256(path)
        if run.digests is not None and digest not in (accepted_digests(run, run_dir, name) or ()):
            raise NgsimInputError(path, ALTERED)
        settled[name] = (digest,)
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
) -> tuple[RunState, RunInfo]:
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
            write_record(run_dir, info, _settled_digests(run_dir))
            drop_rows_after(run_dir, state.next_epoch)
        return state, info
    if is_writer:  # the other ranks of a distributed run would see rank 0 writing run.json
        _start_over(run_dir, info)
    return RunState(), info


def _start_over(run_dir: Path, info: RunInfo) -> None:
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
        write_record(run_dir, info, {})
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
    write_horizons(group)


def _resume(
    run_dir: Path,
    build_dir: Path,
    info: RunInfo,
    model: nn.Module,
    optimizer: torch.optim.Optimizer,
) -> RunState:
    last = run_dir / LAST
    if not last.is_file():
        raise NgsimInputError(run_dir, f"nothing to resume: no {LAST}")
    run = read_record(run_dir)
    checkpoint = load_checkpoint(last, LAST_KEYS, accepted_digests(run, run_dir, LAST))
    check_same_run(checkpoint.info, run.info, last)
    check_resume(run_dir, build_dir, checkpoint.info, info)
    check_weights(model.state_dict(), checkpoint.weights, last)
    check_log(run_dir, checkpoint.state.next_epoch)
    model.load_state_dict(checkpoint.weights)
    _load_optimizer(optimizer, checkpoint.optimizer, last)
    return checkpoint.state


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


def end_epoch(
    run_dir: Path,
    state: RunState,
    info: RunInfo,
    epoch: int,
    train_loss: float,
    val_loss: float,
    model: nn.Module,
    optimizer: torch.optim.Optimizer,
    is_writer: bool,
    timing: dict[str, float] | None = None,
) -> tuple[RunState, EpochRow]:
    """Log the epoch (with `timing`: EpochRow's fields of seconds, graphs/s and learning rate),
    keep the best model, and checkpoint with the run's `info`; returns the new state and the
    epoch's row."""
    better = math.isfinite(val_loss) and val_loss < state.best_val_loss
    new = RunState(
        next_epoch=epoch + 1,
        best_epoch=epoch if better else state.best_epoch,
        best_val_loss=val_loss if better else state.best_val_loss,
    )
    row = EpochRow(epoch + 1, train_loss, val_loss, new.best_epoch + 1, **(timing or {}))
    if not is_writer:
        return new, row
    kept = {}
    if better:
        kept[BEST] = best_bytes(info, model.state_dict(), epoch)
    kept[LAST] = last_bytes(info, model.state_dict(), optimizer.state_dict(), new)
    # run.json accepts each checkpoint's present bytes and its new ones while it is replaced,
    # then the new ones alone: a kill at any point leaves checkpoints that load.
    digests = read_record(run_dir).digests or {}
    new_digests = {name: checkpoint_sha256(data) for name, data in kept.items()}
    replacing = {name: (*digests.get(name, ()), d) for name, d in new_digests.items()}
    write_record(run_dir, info, {**digests, **replacing})
    if BEST in kept:
        write_atomic(run_dir / BEST, kept[BEST])
    append_row(run_dir, row)
    write_atomic(run_dir / LAST, kept[LAST])
    write_record(run_dir, info, {**digests, **{name: (d,) for name, d in new_digests.items()}})
    unmark_started(run_dir)  # a checkpoint is kept: a fresh fit may no longer start over here
    return new, row


def plot_curves(run_dir: Path, synthetic: bool = False) -> Path | None:
    """Training and validation loss per epoch, the best epoch and constant velocity's validation
    loss as a PNG (aigem.runs.curves), titled with how many of its epochs the run trained
    (aigem.runs.course), marked SYNTHETIC where the run's build is of synthetic data;
    None before the first epoch."""
    from aigem.runs.curves import curves_png  # matplotlib (a second to import), only when drawing

    rows = read_metrics(run_dir)
    if not rows:
        return None
    horizon_s = read_record(run_dir).info.train.horizon_s
    course = course_of(run_dir)
    trained = course.words() + ("" if course.finished else " (UNFINISHED: continue with --resume)")
    picture = curves_png(rows, read_baseline(run_dir), horizon_s, synthetic, trained)
    write_atomic(run_dir / CURVES, picture)
    return run_dir / CURVES


# ------------------------------------------------------------------------------------------------
# After an interruption: what a fit that kept nothing leaves.


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
