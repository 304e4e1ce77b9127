"""`aigem evaluate`: a run scored beside constant velocity and the paper, its checks before
PyTorch loads, and the pictures of --plots (aigem.evaluation.evaluate does the work; evaluation_view
prints)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from aigem.config import DeviceChoice
from ngsim_cli.command_line import option_values
from ngsim_cli.console import print_error, print_warning, stdout
from ngsim_cli.exits import check_device, exit_on_error, exit_on_interrupt
from ngsim_cli.progress import progress_bar
from ngsim_graphs.config import check_count
from ngsim_graphs.schema import Split

if TYPE_CHECKING:
    from aigem.evaluation.results import Evaluation


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
    split: Annotated[Split, typer.Option(help="The split to score.")] = Split.TEST,
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
    device: Annotated[
        DeviceChoice, typer.Option(help="auto (CUDA when present), cpu or cuda.")
    ] = DeviceChoice.AUTO,
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
    bootstrap: Annotated[
        int,
        typer.Option(
            "--bootstrap",
            metavar="N",
            help="Resamples of the split's samples for the 95 % intervals of the numbers over all "
            "actors and of their difference to constant velocity (seed 0); 0: no intervals.",
        ),
    ] = 1000,
) -> None:
    """ADE, FDE and RMSE at 1..5 s (metres) of the run's best model and of constant velocity. A
    multi-horizon run (fit --horizon-s 1,2,3,4,5) as the paper reports it: RMSE at h s from the
    h s model, ADE and FDE from the longest-horizon model."""
    with option_values({"bootstrap": "--bootstrap"}):
        check_count("bootstrap", bootstrap, 0)
    with exit_on_interrupt("nothing written"):  # the checks, then PyTorch loads (seconds)
        from aigem.runs.records import BEST, UNRECORDED, unrecorded_checkpoints
        from aigem.runs.refusals import check_evaluate

        with exit_on_error():  # the run and the build, before PyTorch
            check_evaluate(run, data, split, other_build)
            for path in unrecorded_checkpoints(run, (BEST,)):
                print_warning(f"{path}: {UNRECORDED}")
        check_device(device.value)
        from aigem.devices import DeviceUnavailableError
        from aigem.evaluation.evaluate import evaluate as run_evaluate
        from aigem.evaluation.results import as_dict
        from ngsim_cli.evaluation_view import print_evaluation, warn_unfinished

    left = "nothing written" if plots is None else f"{plots} may hold some of this call's pictures"
    with exit_on_interrupt(left), exit_on_error(), progress_bar() as progress:
        scored = lambda done, total: progress(f"evaluating the {split.value} split", done, total)
        try:
            result = run_evaluate(
                run,
                data,
                split.value,
                device.value,
                progress=scored,
                other_build=other_build,
                resamples=bootstrap,
            )
        except DeviceUnavailableError as err:  # the project's own errors: exit_on_error
            print_error(str(err))
            raise typer.Exit(1) from None
        drawn = _draw(result, run, plots, device.value) if plots is not None else []
    if as_json:
        typer.echo(json.dumps(as_dict(result), indent=2))
        warn_unfinished(result)
        return
    print_evaluation(result)
    if drawn:
        scenes = "" if result.same_build else " (no scenes: drawn on the run's own build only)"
        stdout.print(f"Plots in {plots}: {', '.join(path.name for path in drawn)}{scenes}")


def _draw(result: Evaluation, run: Path, folder: Path, device: str) -> list[Path]:
    """The pictures of `evaluate --plots`; returns the paths written."""
    from aigem.figures.pictures import write_evaluation_plots

    return write_evaluation_plots(result, folder, run, device)
