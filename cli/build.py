"""`ngsim-graphs build`: its options (the datasets and locations named from the sources'
registry), BuildConfig checked as a build checks it, the run with a progress bar, and the
build's report (ngsim_graphs.pipeline does the work; build_view prints)."""

from __future__ import annotations

from enum import Enum
from pathlib import Path
from typing import Annotated

import typer

from ngsim_cli.build_view import print_build_report
from ngsim_cli.command_line import checked_config, option_values
from ngsim_cli.exits import exit_on_error, exit_on_interrupt
from ngsim_cli.logs import command_log
from ngsim_cli.progress import progress_bar
from ngsim_graphs.budget import available_cores
from ngsim_graphs.config import DEFAULT_EDGE_TYPES, MAX_PARALLEL, BuildConfig, check_count
from ngsim_graphs.layout import build_log_path
from ngsim_graphs.pipeline import check_config, run_build
from ngsim_graphs.schema import Protocol, SplitMode
from ngsim_graphs.sources.registry import dataset_names, labels_in_words, locations_in_words

# `build --dataset`: told from the files (auto), or forced: the registry's sources.
DatasetChoice = Enum(  # type: ignore[misc]
    "DatasetChoice", {"AUTO": "auto", **{name.upper(): name for name in dataset_names()}}, type=str
)


def _build_config(**options):  # type: ignore[no-untyped-def]
    """The BuildConfig of the options, checked as a build checks it (`pipeline.check_config`)."""
    config = BuildConfig(**options)
    check_config(config)
    return config


# `build`'s help names the registered datasets (`sources.registry`): a new source needs no edit.
BUILD_HELP = f"""Read raw {labels_in_words()} files and write the graph dataset.

RAW_PATH...: {labels_in_words()} files, or folders to search for them (one or more).

Rows beyond their dataset's physical limits (speed, acceleration, position, frame range, a jump
between frames) or that fail one of its own checks are dropped one by one, counted per reason
and reported; more than 1 % of a file's rows is an error (so is any, with --strict). A build that
ends with no samples is an error that says why.
"""


def build(
    raw_paths: Annotated[
        list[Path],
        # Said in BUILD_HELP: typer would show its type as "<list[Path]>".
        typer.Argument(metavar="RAW_PATH", hidden=True),
    ],
    out: Annotated[Path, typer.Option("--out", help="Output directory of the build.")],
    locations: Annotated[
        str,
        typer.Option(
            help=f"Comma-separated locations to keep, by dataset. {locations_in_words()}."
        ),
    ] = "us-101,i-80",
    stride_s: Annotated[
        float,
        typer.Option(
            help="Time between the starts of two windows of one ego track, s: a multiple of the "
            "0.2 s grid step (8: non-overlapping 8 s windows; 0.2: a window at every step)."
        ),
    ] = 8.0,
    d_sense_m: Annotated[
        float,
        typer.Option(
            help="A vehicle at most this far from the ego at a history step is a node, m."
        ),
    ] = 50.0,
    d_min_m: Annotated[
        float,
        typer.Option(
            help="Two actor nodes at most this far apart share spatial edges, m (0: only ego-actor "
            "edges)."
        ),
    ] = 25.0,
    split: Annotated[
        SplitMode,
        typer.Option(
            help="How ego windows are divided into train/val/test: vehicle (CS-LSTM's rule, "
            "per recording: egos with Vehicle_ID up to 70 % of the recording's largest id train, "
            "up to 80 % validate, the rest test; the shares of samples differ from 70/10/20 and "
            "the build prints them), time (contiguous blocks of 70/10/20 of the windows, a "
            "window's length apart), random (70/10/20 of the ego tracks, seeded)."
        ),
    ] = SplitMode.VEHICLE,
    seed: Annotated[
        int, typer.Option(help="Seed of the random split (other splits ignore it).")
    ] = 0,
    ego_target: Annotated[
        bool,
        typer.Option(help="Also predict the ego (by default only the actors at the present step)."),
    ] = False,
    overwrite: Annotated[
        bool,
        typer.Option(
            help="Replace an existing build in --out (never a folder that is not a build)."
        ),
    ] = False,
    min_heading_speed_mps: Annotated[
        float, typer.Option(help="Below this speed the last heading is held, m/s.")
    ] = 2.0,
    heading_smoothing_s: Annotated[
        float, typer.Option(help="Centred moving average of positions before the heading, s.")
    ] = 1.0,
    strict: Annotated[
        bool,
        typer.Option(
            help="Fail on the first implausible or stray row instead of dropping and counting it."
        ),
    ] = False,
    dataset: Annotated[
        DatasetChoice,
        typer.Option(
            help="Which dataset the inputs are: auto tells it from the files' content; inputs "
            f"holding the files of several need one: {', '.join(dataset_names())}."
        ),
    ] = DatasetChoice.AUTO,
    protocol: Annotated[
        Protocol,
        typer.Option(
            help="Which samples: aigem (ego windows at --stride-s, the actors around the ego as "
            "targets) or cs-lstm (the literature's: a sample per row that CS-LSTM's "
            "preprocess_data.m keeps, on the 0.2 s grid, split by its vehicle rule, the row's "
            "vehicle the only target; the six US-101 and I-80 recordings only)."
        ),
    ] = Protocol.AIGEM,
    edge_types: Annotated[
        str,
        typer.Option(
            help="Comma-separated edge types of the graphs, in order: spatial (ego-actor, and "
            "actor-actor within --d-min-m, at a step), temporal (a vehicle's node to its next)."
        ),
    ] = ",".join(DEFAULT_EDGE_TYPES),
    jobs: Annotated[
        int | None,
        typer.Option(
            help="Worker processes that read the input files and build the recordings at once "
            "(default: one per core this process may use). The output is the same for any "
            "number; peak memory grows with it, about 0.25 GB per job at full NGSIM scale.",
            show_default=False,
        ),
    ] = None,
) -> None:
    """Build the graph dataset: its help is BUILD_HELP."""
    config = checked_config(
        _build_config,
        {"ego_is_target": "--ego-target"},
        locations=tuple(name.strip().lower() for name in locations.split(",") if name.strip()),
        stride_s=stride_s,
        d_sense_m=d_sense_m,
        d_min_m=d_min_m,
        split=split,
        seed=seed,
        ego_is_target=ego_target,
        min_heading_speed_mps=min_heading_speed_mps,
        heading_smoothing_s=heading_smoothing_s,
        protocol=protocol,
        edge_types=tuple(name.strip() for name in edge_types.split(",") if name.strip()),
    )
    if jobs is not None:
        with option_values({"jobs": "--jobs"}):
            check_count("jobs", jobs, 1, MAX_PARALLEL)
    left = f"nothing written ({out} is as it was)"
    # The log lands with the build: kept until it has, dropped with a build that fails.
    with command_log(build_log_path(out), ready=lambda: False) as log:
        with exit_on_interrupt(left), exit_on_error(), progress_bar() as progress:
            chosen = None if dataset is DatasetChoice.AUTO else dataset.value
            result = run_build(
                raw_paths,
                out,
                config,
                overwrite=overwrite,
                progress=progress,
                strict=strict,
                dataset=chosen,
                jobs=jobs or available_cores(),
            )
        log.settle()
        print_build_report(result)
