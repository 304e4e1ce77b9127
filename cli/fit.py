"""`aigem fit`: its options, TrainConfig and ModelConfig, the checks before PyTorch loads, --out's
lock, and the training with a progress bar and a line per epoch (aigem.training.fit does the work;
fit_view prints)."""

from __future__ import annotations

import os
import signal
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from aigem.config import (
    DeviceChoice,
    LrSchedule,
    ModelConfig,
    TrainConfig,
    option_words,
    parse_horizons_s,
)
from ngsim_cli.command_line import in_option_words, option_values, usage_error
from ngsim_cli.console import print_error, print_warning
from ngsim_cli.exits import check_device, exit_on_error, exit_on_interrupt
from ngsim_cli.fit_view import (
    discard_if_nothing_kept,
    interrupted,
    print_epoch,
    print_results,
    running_losses,
    say,
)
from ngsim_cli.logs import command_log
from ngsim_cli.progress import progress_bar
from ngsim_graphs.errors import NgsimError

if TYPE_CHECKING:
    from aigem.runs.records import Group
    from aigem.training.fit import FitResult


FIT_OPTIONS = option_words()  # TrainConfig's and ModelConfig's fields by their options


@contextmanager
def _option_words(options: dict[str, str]) -> Iterator[None]:
    """The project's errors about a setting, naming the option that sets it (in_option_words)."""
    try:
        yield
    except NgsimError as err:
        raise type(err)(err.path, in_option_words(err.message, options), err.line) from None


def fit(
    data: Annotated[
        Path, typer.Argument(metavar="DATA", help="A finished ngsim-graphs build directory.")
    ],
    out: Annotated[
        Path, typer.Option("--out", help="Run directory: checkpoints, metrics log, curves.")
    ],
    horizon_s: Annotated[
        str,
        typer.Option(
            metavar="S[,S...]",
            help="Prediction horizon, s, in (0, 5], a multiple of the 0.2 s time step; or "
            "several, comma-separated: 1,2,3,4,5 trains one model per horizon (the paper's "
            "protocol) in one loop over the data, into RUN/h1s ... RUN/h5s, and `aigem evaluate "
            "RUN` scores them as the paper does.",
        ),
    ] = "5",
    epochs: Annotated[int, typer.Option(help="Epochs over the train split.")] = 100,
    batch_size: Annotated[int, typer.Option(help="Graphs (samples) per batch.")] = 32,
    learning_rate: Annotated[
        float, typer.Option(help="Adam's learning rate (the paper's: 1e-3), after any warm-up.")
    ] = 1e-3,
    lr_schedule: Annotated[
        LrSchedule,
        typer.Option(
            help="constant (the paper's), or cosine: the learning rate falls to 0 along half a "
            "cosine by the end of --epochs."
        ),
    ] = LrSchedule.CONSTANT,
    warmup_epochs: Annotated[
        float,
        typer.Option(
            help="Raise the learning rate linearly from near 0 over this many epochs (fractions "
            "allowed) before the schedule."
        ),
    ] = 0.0,
    clip_grad_norm: Annotated[
        float | None,
        typer.Option(help="Scale the gradients down to this total L2 norm where it is larger."),
    ] = None,
    max_minutes: Annotated[
        float | None, typer.Option(help="Stop training after this many minutes.")
    ] = None,
    patience: Annotated[
        int | None,
        typer.Option(help="Stop after this many epochs without a better validation loss."),
    ] = None,
    device: Annotated[
        DeviceChoice, typer.Option(help="auto (CUDA when present), cpu or cuda.")
    ] = DeviceChoice.AUTO,
    seed: Annotated[
        int, typer.Option(help="Seed of the initialisation, shuffling and dropout.")
    ] = 0,
    workers: Annotated[
        int | None,
        typer.Option(
            help="DataLoader worker processes (default: on a GPU all cores but two, at most 12; "
            "on the CPU 1 from 4 cores up, else 0)."
        ),
    ] = None,
    threads: Annotated[
        int | None,
        typer.Option(
            help="CPU threads of the model step (default: the usable cores that other processes "
            "leave idle, looked at again every 10 s). A number gives bit-reproducible runs, but "
            "keep it to the idle cores: a thread without a core of its own stalls every "
            "operator (one busy core of two: 6 instead of 314 graphs/s), and fit warns when it "
            "starts on fewer idle cores than threads."
        ),
    ] = None,
    resident: Annotated[
        bool | None,
        typer.Option(
            "--resident/--loader",
            help="Load the train and validation splits onto the device once and train on "
            "static batches assembled there, each step captured once and replayed on CUDA "
            "(default: on CUDA, where the splits take at most half its free memory); "
            "--loader: the DataLoader's batches (the CPU's default).",
        ),
    ] = None,
    compile_decoder: Annotated[
        bool | None,
        typer.Option(
            "--compile/--no-compile",
            help="Run the decoder through torch.compile on the DataLoader's batches (default: "
            "on CUDA, where it saves some 2,000 kernel launches a step; on the CPU it costs a "
            "minute and gains nothing; a captured step on static batches needs none).",
        ),
    ] = None,
    no_concat: Annotated[
        bool,
        typer.Option(
            "--no-concat", help="Ablation: the output MLP does not see the previous position."
        ),
    ] = False,
    cv_residual: Annotated[
        bool,
        typer.Option(
            "--cv-residual",
            help="Beyond the paper, never the default: each step's displacement is constant "
            "velocity's (the present speed along the present heading) plus the output MLP's, "
            "so the model learns the correction to constant velocity (docs/aigem.md).",
        ),
    ] = False,
    resume: Annotated[
        bool, typer.Option(help="Continue the run in --out from its last checkpoint.")
    ] = False,
) -> None:
    """Train AiGem on DATA's train split; keep the best model by validation loss."""
    try:
        horizons_s = parse_horizons_s(horizon_s)
    except ValueError as err:
        raise usage_error(f"--horizon-s {horizon_s}: {err}") from None
    with option_values(FIT_OPTIONS):
        train = TrainConfig(
            horizon_s=horizons_s[0],
            epochs=epochs,
            batch_size=batch_size,
            learning_rate=learning_rate,
            lr_schedule=lr_schedule.value,
            warmup_epochs=warmup_epochs,
            clip_grad_norm=clip_grad_norm,
            max_minutes=max_minutes,
            patience_epochs=patience,
            seed=seed,
            workers=workers,
            threads=threads,
            compile=compile_decoder,
            resident=resident,
        )
    model_config = ModelConfig(concat_position=not no_concat, cv_residual=cv_residual)
    with _held(out):  # one fit at a time into --out, as build and paper
        with exit_on_interrupt("nothing written"):  # the checks, then PyTorch loads (seconds)
            from aigem.runs.records import UNRECORDED, planned_group, unrecorded_checkpoints
            from aigem.runs.refusals import check_fit

            group = planned_group(out, horizons_s)
            with exit_on_error(), _option_words(FIT_OPTIONS):  # the build and --out
                check_fit(data, group, model_config, train, resume)
                for path in unrecorded_checkpoints(out) if resume else []:
                    print_warning(f"{path}: {UNRECORDED}; recorded as they are from now on")
            check_device(device.value)  # PyTorch alone, before the rest loads
            import aigem.training.fit  # noqa: F401  (loaded here, where an interrupt is one line)
        with _fit_log(group) as training:
            results = _train(data, group, model_config, train, device.value, resume, training)
    print_results(results, out)


@contextmanager
def _fit_log(group: Group) -> Iterator[Callable[[], None]]:
    """RUN/fit.log (records.FIT_LOG) for the block: its lines kept until the returned function
    says that training runs (the run's checks are passed, its folder is fit's: a refused fit
    writes nothing into it), then appended. Under torchrun, rank 0's only."""
    from aigem.runs.records import FIT_LOG

    if int(os.environ.get("RANK", "0")) > 0:
        yield lambda: None
        return
    with command_log(group.run_dir / FIT_LOG, ready=lambda: False) as log:
        yield log.settle


@contextmanager
def _held(out: Path) -> Iterator[None]:
    """Hold --out's lock for the block (ngsim_graphs.lock: `.OUT.lock` beside it, as a build's
    and a paper's): a second fit, build or paper into the same folder meanwhile is refused with
    one line, and the lock goes with this process, however it ends. Under torchrun only rank 0
    holds it: the other ranks write nothing into --out."""
    from ngsim_graphs.lock import output_lock

    if int(os.environ.get("RANK", "0")) > 0:  # torchrun's: rank 0's lock covers the fit
        yield
        return
    with ExitStack() as held:
        with exit_on_interrupt("nothing written"), exit_on_error():
            out.parent.mkdir(parents=True, exist_ok=True)  # where the lock is
            held.enter_context(output_lock(out.resolve()))  # `--out .` has a name
        yield


def _train(
    data: Path,
    group: Group,
    model_config: ModelConfig,
    train: TrainConfig,
    device: str,
    resume: bool,
    training: Callable[[], None],
) -> tuple[FitResult, ...]:
    """fit_horizons with a progress bar and a line per epoch, once the options are checked;
    `training` is called as each batch is trained (fit.log is written from the first)."""
    from aigem.cores import busy_cores_warning
    from aigem.devices import DeviceUnavailableError
    from aigem.training.epochs import NonFiniteLossError
    from aigem.training.fit import fit_horizons

    if train.threads is not None and (warning := busy_cores_warning(train.threads)):
        print_warning(warning)
    out = group.run_dir
    who = (lambda h: f"{h:g} s model, ") if group.named else (lambda h: "")
    created = not out.exists()
    with exit_on_error(), _interrupt_on_sigterm(), progress_bar() as progress:
        # One bar over the run's epochs, so that its ETA is the run's (at the rate of the
        # recent batches; validation and early stopping are not foreseen).
        def show(epoch: int, done: int, total: int, losses: tuple[float, ...]) -> None:
            training()
            progress(
                f"epoch {epoch}/{train.epochs}",
                (epoch - 1) * total + done,
                train.epochs * total,
                running_losses(losses),
            )

        on_epoch = lambda horizon_s, row: print_epoch(row, who(horizon_s))
        loading = lambda what, done, total: progress(f"loading {what}", done, total)
        try:
            return fit_horizons(
                data,
                out,
                group.horizons_s,
                model_config,
                train,
                device,
                resume,
                show,
                on_epoch,
                loading,
                say,
            )
        except KeyboardInterrupt:
            raise interrupted(group, created) from None
        except (NgsimError, NonFiniteLossError, DeviceUnavailableError) as err:
            discard_if_nothing_kept(group, created)
            if isinstance(err, NgsimError):
                raise  # exit_on_error says it
            print_error(str(err))
            raise typer.Exit(1) from None


@contextmanager
def _interrupt_on_sigterm() -> Iterator[None]:
    """SIGTERM (a `kill`, a job scheduler's stop) ends training as Ctrl-C does: with the files
    written whole (they are written to a .partial name and renamed) and a line saying what is
    kept, rather than the silent death that SIGTERM's default is."""

    def interrupt(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    before = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, before)
