"""`aigem paper`: the paper's experimental section in one command (aigem.paper.experiments does the work)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from aigem.config import DeviceChoice
from aigem.paper.folder import PAPER_EPOCHS
from aigem.paper.plan import PARTS
from aigem.paper_layout import PAPER_JSON, PAPER_LOG
from ngsim_cli.command_line import option_names, option_values, usage_error
from ngsim_cli.console import print_error, print_warning, stdout
from ngsim_cli.exits import check_device, exit_on_error, exit_on_interrupt
from ngsim_cli.fit_view import print_epoch
from ngsim_cli.logs import command_log

if TYPE_CHECKING:
    from aigem.paper.folder import PaperConfig
    from aigem.paper.plan import PaperCall
from ngsim_cli.progress import progress_bar

PARTS_HELP = ",".join(PARTS)  # every part, in the report's order
# PaperConfig's and PaperCall's fields set by an option (of another name: --patience)
PAPER_OPTIONS = option_names(
    ("epochs", "patience_epochs", "seed", "batch_size", "max_hours", "seeds", "threads", "jobs"),
    {"patience_epochs": "--patience"},
)


def paper(
    raw_paths: Annotated[
        list[Path],
        # Said in the docstring: typer would show its type as "<list[Path]>".
        typer.Argument(metavar="RAW_PATH", hidden=True),
    ],
    out: Annotated[
        Path,
        typer.Option(
            "--out",
            help="Folder of the whole work: new or empty, or one an earlier call with the same "
            "settings left (it continues).",
        ),
    ],
    epochs: Annotated[
        int, typer.Option(help=f"Epochs of each model (the paper's: {PAPER_EPOCHS}).")
    ] = PAPER_EPOCHS,
    patience: Annotated[
        int | None,
        typer.Option(help="Stop a model after this many epochs without a better validation loss."),
    ] = None,
    batch_size: Annotated[int, typer.Option(help="Graphs (samples) per batch.")] = 32,
    seed: Annotated[
        int,
        typer.Option(
            help="Seed of the initialisation, shuffling and dropout: the first seed of --seeds."
        ),
    ] = 0,
    seeds: Annotated[
        int,
        typer.Option(
            help="Train each fit this many times, at --seed, --seed + 1, ...: each number of the "
            "report is then the mean over the seeds with its 95 % interval, and each ablation's "
            "difference says whether it is beyond the noise. More seeds later train the new "
            "seeds' runs alone.",
        ),
    ] = 1,
    only: Annotated[
        str,
        typer.Option(
            metavar="PART[,PART...]",
            help="The parts of the report (it then holds only those), and so the builds and "
            "fits they need: table, curves and regions the paper's model (d_min 25 m); dmin also "
            "the fits of d_min 0 and 50 m; concat also the d_min 25 m fit without the output "
            "concatenation.",
        ),
    ] = PARTS_HELP,
    max_hours: Annotated[
        float | None,
        typer.Option(
            help="Time for the training (the builds and the evaluations come on top): each fit "
            "still to train gets an equal share of what is left and keeps its last whole epoch; "
            "the report then says UNFINISHED, and the same command again continues.",
        ),
    ] = None,
    device: Annotated[
        DeviceChoice, typer.Option(help="auto (CUDA when present), cpu or cuda.")
    ] = DeviceChoice.AUTO,
    threads: Annotated[
        int | None,
        typer.Option(
            help="CPU threads of the model step and the evaluations (default: the idle cores, as "
            "`aigem fit`); a number gives bit-reproducible results.",
        ),
    ] = None,
    jobs: Annotated[
        int | None,
        typer.Option(
            help="Worker processes of the builds (default: one per core this process may use).",
            show_default=False,
        ),
    ] = None,
    overwrite: Annotated[
        bool,
        typer.Option(
            "--overwrite",
            help="Continue in an --out that an earlier call with other settings left: the builds "
            "whose config or inputs differ are rebuilt and their runs start over; all runs start "
            "over for another seed, batch size or patience, or fewer epochs (more continue them); "
            "never a folder not of `aigem paper`.",
        ),
    ] = False,
) -> None:
    """Run the paper's experiments on RAW_PATH... (NGSIM files, or folders to search for them;
    unpacked: a .zip or .gz is refused, docs/reproduce.md unpacks NGSIM's zips): 3 builds (d_min 0,
    25, 50 m), 4 fits of 5 models each (1..5 s;
    d_min 25 m with and without the output concatenation, d_min 0 and 50 m), their evaluations
    on the test split, and OUT/report.md, OUT/report.json and OUT/figures/: Table 1 beside the
    published rows, the d_min and concatenation ablations, the training curves and front / mid /
    rear. Every table and figure says SYNTHETIC (PARTLY SYNTHETIC) where all (some) inputs came
    from `ngsim-graphs synth`. --seeds N trains every fit N times (the builds are made once):
    each AiGem number is then the mean over the seeds with its 95 % interval, and each ablation
    says whether its difference to the paper's configuration is beyond the noise.

    Time, on 2 idle CPU cores: about 2.5 minutes with --epochs 2 on the README's demo input (2
    recordings of 2 minutes); 14.5 minutes with --epochs 1 on two synthetic 15-minute recordings;
    six recordings at the paper's 100 epochs some 70 to 90 hours (extrapolated from six synthetic
    ones: docs/reproduce.md). Where other work shares the cores, 2.5 to 4.5 times as long.

    Ctrl-C keeps the finished builds and each model's last epoch: the same command continues.
    --max-hours bounds the training only (builds and evaluations come on top); a report of fits
    it stopped says UNFINISHED, and the same command again continues them.
    """
    from aigem.paper.folder import PaperConfig, check_folder, paper_document
    from aigem.paper.plan import PaperCall, parse_parts, plan_seeds  # light: no PyTorch yet

    try:
        parts = parse_parts(only)
    except ValueError as err:
        raise usage_error(f"--only {only}: {err}") from None
    with option_values(PAPER_OPTIONS):
        config = PaperConfig(epochs, patience, seed, batch_size)
        plan_seeds(
            config,
            PaperCall(
                threads=threads, max_hours=max_hours, jobs=1 if jobs is None else jobs, seeds=seeds
            ),
        )
    with exit_on_interrupt("nothing written"), exit_on_error():  # before PyTorch loads
        check_folder(out, paper_document(raw_paths, config), overwrite)
    left = lambda: _left(out)  # noqa: E731
    with exit_on_interrupt(left):  # PyTorch loads (seconds): no CUDA is said at once
        check_device(device.value)
        import aigem.paper.experiments  # noqa: F401  (loaded here, where an interrupt is one line)
        from aigem.cores import busy_cores_warning
        from ngsim_graphs.budget import available_cores
    # The log goes into --out once it is ours (paper.json: a new folder is claimed first).
    with command_log(out / PAPER_LOG, lambda: (out / PAPER_JSON).is_file()):
        if threads is not None and (warning := busy_cores_warning(threads)):
            print_warning(warning)
        call = PaperCall(
            parts, device.value, threads, max_hours, jobs or available_cores(), overwrite, seeds
        )
        report = _run(raw_paths, out, config, call)
    _print_summary(report, out)


def _run(raw_paths: list[Path], out: Path, config: PaperConfig, call: PaperCall) -> dict:
    """run_paper with a progress bar and a line per epoch; its report.json document."""
    from aigem.devices import DeviceUnavailableError
    from aigem.paper.experiments import run_paper
    from aigem.paper.training import TimeLimitError
    from aigem.training.epochs import NonFiniteLossError

    with exit_on_interrupt(lambda: _left(out)), exit_on_error(), progress_bar() as progress:
        try:
            on_epoch = lambda fit, horizon_s, row: print_epoch(
                row, f"{fit}, {horizon_s:g} s model, "
            )
            return run_paper(raw_paths, out, config, call, progress, on_epoch).report
        except (NonFiniteLossError, DeviceUnavailableError, TimeLimitError) as err:
            print_error(str(err))
            raise typer.Exit(1) from None


def _left(out: Path) -> str:
    """What an interrupted call leaves: nothing before it made `out`."""
    if not out.is_dir():
        return "nothing written"
    return (
        f"{out} keeps the finished builds and each model's last finished epoch, and no report; "
        "run the same command again to continue"
    )


def _print_summary(report: dict, out: Path) -> None:
    """Where the report is, the paper's model's RMSE beside the paper's, and, where --max-hours
    left a fit unfinished, that the report is unfinished (last)."""
    from aigem.paper.report_cells import SECONDS, shown
    from aigem.paper.report_tables import data_mark
    from aigem.paper.report_text import UNFINISHED

    mark = data_mark(report)
    kind = f" ({mark} data: not comparable to the paper's NGSIM numbers)" if mark else ""
    if "table1" in report:
        ours = report["table1"]["ours"]["AiGem (this run)"]
        paper = report["table1"]["published"]["AiGem (paper)"]
        row = lambda cells: ", ".join(shown(cells[f"rmse_{s}s_m"]) for s in SECONDS)  # noqa: E731
        seeds = len(report["seeds"])
        over = f", mean of {seeds} seeds [95 % interval: the training noise]" if seeds > 1 else ""
        if seeds == 1 and report["table1"].get("intervals") is not None:
            over = ", in brackets its 95 % interval: the test-set noise"
        stdout.print(
            f"AiGem RMSE at 1..5 s (m{over}): {row(ours)}{kind}; the paper: {row(paper)}",
            markup=False,  # the intervals' brackets are no markup
        )
    figures = ", ".join(Path(name).name for name in report.get("figures", []))
    stdout.print(f"Report: {out / 'report.md'} and {out / 'report.json'}; figures: {figures}")
    if not report["finished"]:
        fits = ", ".join(report["unfinished_fits"])
        stdout.print(f"{UNFINISHED} (unfinished fits: {fits})", markup=False, highlight=False)
