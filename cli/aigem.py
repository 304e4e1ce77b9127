"""`aigem`: train and evaluate the AiGem trajectory predictor on an ngsim-graphs build."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.table import Table

from aigem import __version__
from ngsim_cli.console import (
    HELP_SETTINGS,
    add_version_option,
    exit_on_error,
    print_table,
    stderr,
    stdout,
)
from ngsim_graphs.synth.marker import SYNTHETIC_LABEL

if TYPE_CHECKING:
    from aigem.evaluation import Evaluation, HorizonsEvaluation
    from aigem.training import FitResult

app = typer.Typer(
    help="AiGem trajectory prediction (GAT + linear encoder, GRU decoder, MLP output).",
    no_args_is_help=True,
    add_completion=False,
    **HELP_SETTINGS,
)


add_version_option(app, "aigem", __version__)


def _fail(message: str, code: int = 1) -> typer.Exit:
    stderr.print(f"error: {message}", markup=False, highlight=False, soft_wrap=True)
    return typer.Exit(code)


@app.command(short_help="Train AiGem on a build (one horizon or the paper's five).")
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
            help="Prediction horizon, s, in (0, 5]; or several, comma-separated: 1,2,3,4,5 trains "
            "one model per horizon (the paper's protocol) in one loop over the data, into "
            "RUN/h1s ... RUN/h5s, and `aigem evaluate RUN` scores them as the paper does."
        ),
    ] = "5",
    epochs: Annotated[int, typer.Option(help="Epochs over the train split.")] = 100,
    batch_size: Annotated[int, typer.Option(help="Graphs (samples) per batch.")] = 32,
    learning_rate: Annotated[
        float, typer.Option(help="Adam's learning rate (the paper's: 1e-3), after any warm-up.")
    ] = 1e-3,
    lr_schedule: Annotated[
        str,
        typer.Option(
            help="constant (the paper's), or cosine: the learning rate falls to 0 along half a "
            "cosine by the end of --epochs."
        ),
    ] = "constant",
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
    device: Annotated[str, typer.Option(help="auto (CUDA when present), cpu or cuda.")] = "auto",
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
            "leave idle, looked at again every 10 s; give a number for bit-reproducible runs)."
        ),
    ] = None,
    compile_decoder: Annotated[
        bool | None,
        typer.Option(
            "--compile/--no-compile",
            help="Run the decoder through torch.compile (default: on CUDA, where it saves some "
            "2,000 kernel launches a step; on the CPU it costs a minute and gains nothing).",
        ),
    ] = None,
    no_concat: Annotated[
        bool,
        typer.Option(
            "--no-concat", help="Ablation: the output MLP does not see the previous position."
        ),
    ] = False,
    resume: Annotated[
        bool, typer.Option(help="Continue the run in --out from its last checkpoint.")
    ] = False,
) -> None:
    """Train AiGem on DATA's train split; keep the best model by validation loss."""
    from aigem.config import ModelConfig, TrainConfig, parse_horizons_s
    from aigem.model import AiGem, count_parameters
    from aigem.training import DeviceUnavailableError, NonFiniteLossError, fit_horizons
    from ngsim_cli.console import progress_bar

    if device not in ("auto", "cpu", "cuda"):
        raise _fail(f"--device must be auto, cpu or cuda, not {device!r}", 2)
    try:
        horizons_s = parse_horizons_s(horizon_s)
    except ValueError as err:
        raise _fail(f"--horizon-s {horizon_s}: {err}", 2) from None
    try:
        train = TrainConfig(
            horizon_s=horizons_s[0],
            epochs=epochs,
            batch_size=batch_size,
            learning_rate=learning_rate,
            lr_schedule=lr_schedule,
            warmup_epochs=warmup_epochs,
            clip_grad_norm=clip_grad_norm,
            max_minutes=max_minutes,
            patience_epochs=patience,
            seed=seed,
            workers=workers,
            threads=threads,
            compile=compile_decoder,
        )
    except ValueError as err:
        raise _fail(str(err), 2) from None
    model_config = ModelConfig(concat_position=not no_concat)
    stdout.print(f"AiGem: {count_parameters(AiGem(model_config)):,} parameters (the paper: 74.5 K)")
    several = len(horizons_s) > 1
    with exit_on_error(), progress_bar() as progress:
        show = lambda epoch, done, total, losses: progress(
            f"epoch {epoch} loss {_losses(losses)} m²", done, total
        )
        on_epoch = lambda horizon_s, row: _print_epoch(
            row, f"{horizon_s:g} s model, " if several else ""
        )
        try:
            results = fit_horizons(
                data,
                out,
                horizons_s if several else None,
                model_config,
                train,
                device,
                resume,
                show,
                on_epoch,
            )
        except (NonFiniteLossError, DeviceUnavailableError) as err:  # the project's: exit_on_error
            raise _fail(str(err)) from None
    _print_results(results, out)


def _print_results(results: tuple[FitResult, ...], out: Path) -> None:
    """A line per model; with several, one more for the run."""
    several = len(results) > 1
    for result in results:
        who = f"{result.horizon_s:g} s model: " if several else ""
        speed = "" if several else f"{result.train_graphs_per_s:,.1f} graphs/s in training. "
        stdout.print(
            f"{who}{result.epochs_done} epochs on {result.device} ({result.stopped_because}); best "
            f"epoch {result.best_epoch}, validation MSE {result.best_val_loss_m2:.3f} m²; "
            f"{speed}Run: {result.run_dir}"
        )
    if several:
        stdout.print(
            f"{len(results)} models trained together at {results[0].train_graphs_per_s:,.1f} "
            f"graphs/s (each graph through every model still training). Run: {out}; "
            f"`aigem evaluate {out}` scores them as the paper reports."
        )


def _losses(losses: tuple[float, ...]) -> str:
    """Running training losses of the progress bar: '-' for a model not training this epoch."""
    return " | ".join("-" if math.isnan(loss) else f"{loss:.3f}" for loss in losses)


def _print_epoch(row: dict[str, float], who: str = "") -> None:
    """One line per epoch on stderr, so that a log of a long run shows its course."""
    best = " (best)" if row["best_epoch"] == row["epoch"] else ""
    stderr.print(
        f"{who}epoch {row['epoch']}: train MSE {row['train_loss_m2']:.3f} m², validation MSE "
        f"{row['val_loss_m2']:.3f} m²{best}; {row['train_seconds']:.0f} s training at "
        f"{row['train_graphs_per_s']:,.0f} graphs/s, {row['val_seconds']:.0f} s validation",
        markup=False,
        highlight=False,
        soft_wrap=True,
    )


def _metrics_table(title: str, rows: dict[str, dict], seconds: int) -> Table:
    table = Table(title=title)
    for column in (
        "model",
        "ADE",
        "FDE",
        *(f"RMSE {s} s" for s in range(1, seconds + 1)),
        "params",
    ):
        table.add_column(column, justify="left" if column == "model" else "right")
    fmt = lambda v: "-" if v is None else f"{v:.2f}"
    for name, row in rows.items():
        rmse = row.get("rmse_m") or [row.get(f"rmse_{s}s_m") for s in range(1, seconds + 1)]
        table.add_row(
            name,
            fmt(row["ade_m"]),
            fmt(row["fde_m"]),
            *(fmt(v) for v in rmse[:seconds]),
            str(row.get("params_k", "")),
        )
    return table


@app.command(short_help="Score a run against constant velocity and the paper.")
def evaluate(
    run: Annotated[
        Path, typer.Argument(metavar="RUN", help="A run directory written by `aigem fit`.")
    ],
    data: Annotated[
        Path | None,
        typer.Option(
            "--data", help="The build to evaluate on (default: the run's own, as recorded by fit)."
        ),
    ] = None,
    split: Annotated[str, typer.Option(help="train, val or test.")] = "test",
    other_build: Annotated[
        bool,
        typer.Option(
            "--other-build",
            help=(
                "Allow a build other than the run's (e.g. train on US-101, test on I-80); inputs "
                "are scaled with the run's scaler."
            ),
        ),
    ] = False,
    as_json: Annotated[
        bool, typer.Option("--json", help="Print one JSON document, nothing else.")
    ] = False,
    device: Annotated[str, typer.Option(help="auto, cpu or cuda.")] = "auto",
    plots: Annotated[
        Path | None,
        typer.Option(
            "--plots",
            metavar="DIR",
            help="Also draw PNGs into DIR (created): error by horizon and by region, the final "
            "error's distribution (beside constant velocity and the paper's points), and the "
            "worst, median and best scenes.",
        ),
    ] = None,
) -> None:
    """ADE, FDE and RMSE at 1..5 s (metres) of the run's best model and of constant velocity. A
    multi-horizon run (fit --horizon-s 1,2,3,4,5) as the paper reports it: RMSE at h s from the
    h s model, ADE and FDE from the longest-horizon model."""
    from aigem.evaluation import PAPER_TABLE, as_dict, evaluate_horizons
    from aigem.evaluation import evaluate as run_evaluate
    from aigem.runs import read_horizons
    from aigem.training import DeviceUnavailableError

    if split not in ("train", "val", "test"):
        raise _fail(f"--split must be train, val or test, not {split!r}", 2)
    if device not in ("auto", "cpu", "cuda"):
        raise _fail(f"--device must be auto, cpu or cuda, not {device!r}", 2)
    with exit_on_error():
        try:
            several = read_horizons(run) is not None
            result = (evaluate_horizons if several else run_evaluate)(
                run, data, split, device, other_build=other_build
            )
        except DeviceUnavailableError as err:  # the project's own errors: exit_on_error
            raise _fail(str(err)) from None
        drawn = _draw(result, run, plots, device) if plots is not None else []
    if as_json:
        typer.echo(json.dumps(as_dict(result), indent=2))
        return
    seconds = sum(key.startswith("rmse_") for key in result.model["all"])
    empty = [
        region
        for region in ("front", "mid", "rear")
        if not any(result.model[region][f"n_{s}s"] for s in range(1, seconds + 1))
    ]
    for region in ("all", "front", "mid", "rear"):
        if region in empty:
            continue
        ours = {**result.model[region], "params_k": round(result.parameters / 1000, 1)}
        rows = {"AiGem (this run)": ours, "constant velocity": result.constant_velocity[region]}
        print_table(_metrics_table(f"{split} split, {region} actors (metres)", rows, seconds))
    if empty:
        stdout.print(f"No {' or '.join(empty)} actors among the targets: no table for them.")
    counts = ", ".join(f"{s} s: {result.model['all'][f'n_{s}s']:,}" for s in range(1, seconds + 1))
    stdout.print(f"{result.samples:,} samples; evaluated actors per horizon: {counts}")
    stdout.print(
        f"Protocol: {result.protocol} ({result.protocol_description})",
        markup=False,
        highlight=False,
        soft_wrap=True,
    )
    if several:
        rmse = ", ".join(
            f"{s} s from {result.sources[f'rmse_{s}s_m']}" for s in range(1, seconds + 1)
        )
        longest, horizon_s = result.sources["ade_m"], result.horizons_s[-1]
        paper = "" if horizon_s == 5 else " (the paper's over 5 s)"
        stdout.print(
            f"One model per horizon: RMSE at {rmse}; ADE and FDE from {longest}, over "
            f"{horizon_s:g} s{paper}. Constant velocity likewise, on the same targets."
        )
    print_table(_metrics_table("the paper's table (NGSIM US-101 + I-80)", PAPER_TABLE, 5))
    other = (
        "" if result.same_build else " (not the run's build; inputs scaled with the run's scaler)"
    )
    kind = (
        f", a build of {SYNTHETIC_LABEL}: synthetic results, not comparable to the paper's NGSIM numbers"
        if result.synthetic
        else ""
    )
    stdout.print(f"These numbers come from {result.build_dir}{other}{kind}.")
    if drawn:
        scenes = "" if result.same_build else " (no scenes: drawn on the run's own build only)"
        stdout.print(f"Plots in {plots}: {', '.join(path.name for path in drawn)}{scenes}")


def _draw(
    result: Evaluation | HorizonsEvaluation, run: Path, folder: Path, device: str
) -> list[Path]:
    """The pictures of `evaluate --plots`; returns the paths written."""
    from aigem.pictures import write_evaluation_plots

    return write_evaluation_plots(result, folder, run, device)


def main() -> None:
    app()


if __name__ == "__main__":
    main()
