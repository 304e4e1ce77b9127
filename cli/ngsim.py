"""`ngsim-graphs`: synthesize NGSIM-format data, build graph datasets, and inspect a build."""

from __future__ import annotations

import json
from enum import Enum
from pathlib import Path
from typing import Annotated

import numpy as np
import polars as pl
import typer

from ngsim_cli.build_view import print_build_report
from ngsim_cli.console import (
    HELP_SETTINGS,
    add_version_option,
    counted,
    exit_on_error,
    exit_on_interrupt,
    naming_the_other_program,
    option_names,
    option_values,
    print_error,
    print_table,
    progress_bar,
    stderr,
    stdout,
    usage_error,
)
from ngsim_cli.cslstm import export_cslstm
from ngsim_cli.show import show
from ngsim_cli.stats_view import STATS_TABLES
from ngsim_graphs import __version__
from ngsim_graphs.budget import available_cores
from ngsim_graphs.build import open_build
from ngsim_graphs.config import (
    DEFAULT_EDGE_TYPES,
    MAX_PARALLEL,
    BuildConfig,
    SynthConfig,
    check_count,
    check_seed,
)
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.pipeline import check_config, run_build
from ngsim_graphs.schema import Protocol, RawFormat, Split, SplitMode
from ngsim_graphs.sources.registry import dataset_names, labels_in_words, locations_in_words
from ngsim_graphs.statistics import MAX_DEGREE_GRAPHS, build_statistics
from ngsim_graphs.synth.marker import SYNTHETIC_LABEL, synthetic_build, synthetic_inputs_of

app = typer.Typer(
    help=f"Vehicle trajectories ({labels_in_words()}) to spatial-temporal graph datasets.",
    no_args_is_help=True,
    add_completion=False,
    cls=naming_the_other_program("aigem", "ngsim_cli.aigem"),
    **HELP_SETTINGS,
)


add_version_option(app, "ngsim-graphs", __version__)


# Config fields set by an option of another name.
RENAMED_OPTIONS = {"ego_is_target": "--ego-target", "raw_format": "--format"}


def _config_or_exit(factory, **kwargs):  # type: ignore[no-untyped-def]
    """The config dataclass, or one line on stderr naming the option and exit status 2 for an
    invalid option."""
    with option_values(option_names(kwargs, RENAMED_OPTIONS)):
        return factory(**kwargs)


@app.command(short_help="Write synthetic NGSIM- or highD-format trajectories.")
def synth(
    out_dir: Annotated[
        Path,
        typer.Argument(
            metavar="OUT_DIR",
            help="Folder to write the files into: new, empty, or one synth wrote before, holding "
            "only its files as written (SYNTHETIC.md lists them with their sha256); it is "
            "replaced whole once the new files are written. Synth never replaces files it did "
            "not write.",
        ),
    ],
    raw_format: Annotated[
        RawFormat,
        typer.Option(
            "--format",
            help="portal: one combined CSV; csv/txt: one file per period; highd: highD's "
            "NN_tracks.csv, NN_tracksMeta.csv, NN_recordingMeta.csv per recording (metres, 25 Hz).",
        ),
    ] = RawFormat.TXT,
    recordings: Annotated[int, typer.Option(help="How many of the six NGSIM periods (1-6).")] = 6,
    minutes: Annotated[
        float,
        typer.Option(
            help="Length of each recording, minutes, from the start of its official period. The "
            "files keep the 15-minute period's name (0400-0415) whatever the length: a build "
            "tells a recording by its start time."
        ),
    ] = 15.0,
    seed: Annotated[int, typer.Option(help="Random seed; the same seed gives the same bytes.")] = 0,
    quirks: Annotated[
        bool,
        typer.Option(
            help='Inject the quirks of real exports (BOM, CRLF, "1,156", duplicates, gaps, ...).'
        ),
    ] = False,
) -> None:
    """Write synthetic NGSIM-shaped trajectories (simulated traffic, NOT real NGSIM data)."""
    config = _config_or_exit(
        SynthConfig,
        raw_format=raw_format,
        recordings=recordings,
        minutes=minutes,
        seed=seed,
        quirks=quirks,
    )
    with exit_on_interrupt(f"nothing written ({out_dir} is as it was)"):
        from ngsim_graphs.synth.formats import period_note, write_synthetic  # only when used

        with exit_on_error(), progress_bar() as progress:
            paths = write_synthetic(out_dir, config, lambda what: progress(what, 0, 0))
    for path in paths:
        stdout.print(f"{path}  {path.stat().st_size / 1e6:.1f} MB")
    if note := period_note(config):
        stdout.print(f"Note: {note}.")


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


@app.command(short_help=f"Build the graph dataset from {labels_in_words()} files.", help=BUILD_HELP)
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
    config = _config_or_exit(
        _build_config,
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
    print_build_report(result)


def _write_plots(values, folder: Path, synthetic: bool) -> list[Path]:  # type: ignore[no-untyped-def]
    """The PNG histograms (a file of their names that is not ours refused: plot_folder)."""
    from ngsim_graphs.plotting import write_histograms  # matplotlib loads only when plotting

    return write_histograms(values, folder, synthetic)


@app.command(short_help="Summarize a build: samples, graph sizes, degrees, plots.")
def stats(
    build_dir: Annotated[Path, typer.Argument(metavar="DIR", help="A finished build directory.")],
    as_json: Annotated[
        bool, typer.Option("--json", help="Print one JSON document, nothing else.")
    ] = False,
    plots: Annotated[
        Path | None,
        typer.Option(
            "--plots",
            help="Folder to write PNG histograms into (created); files of their names that an "
            "earlier --plots did not write (plots.json lists ours) are never replaced.",
        ),
    ] = None,
    degree_graphs: Annotated[
        int,
        typer.Option(help="Graphs per split induced (at random) for the node-degree statistics."),
    ] = MAX_DEGREE_GRAPHS,
    seed: Annotated[int, typer.Option(help="Seed of the random choice of those graphs.")] = 0,
) -> None:
    """Check a build before training: samples, graph sizes, degrees, kinematics, scaler, config."""
    with option_values({"seed": "--seed", "degree_graphs": "--degree-graphs"}):
        check_seed("seed", seed)
        check_count("degree_graphs", degree_graphs, 1)
    with exit_on_error():
        opened = open_build(build_dir)
        try:
            statistics, values = build_statistics(opened, degree_graphs, seed)
        except OSError as err:  # a file listed in the manifest is gone
            raise NgsimInputError(build_dir, f"incomplete build: {err}") from None
        synthetic = synthetic_build(opened.manifest)
        synthetic_files = synthetic_inputs_of(opened.manifest)
        written = _write_plots(values, plots, synthetic) if plots is not None else []
    if as_json:
        document = statistics.to_dict() | {
            "synthetic": synthetic,
            "synthetic_inputs": list(synthetic_files),
            "plots": [str(path) for path in written],
        }
        typer.echo(json.dumps(document, indent=2))
        return
    if synthetic:
        stdout.print(f"{build_dir}: {SYNTHETIC_LABEL}.", markup=False, highlight=False)
    elif synthetic_files:
        stdout.print(
            f"{build_dir}: {len(synthetic_files)} of {len(opened.manifest.inputs)} inputs are "
            f"{SYNTHETIC_LABEL} (the manifest's synthetic_inputs).",
            markup=False,
            highlight=False,
            soft_wrap=True,
        )
    for make_table in STATS_TABLES:
        print_table(make_table(statistics))
    for path in written:
        stdout.print(f"wrote {path}")
    for warning in statistics.warnings:
        stderr.print(f"warning: {warning}", markup=False, highlight=False, soft_wrap=True)


@app.command(short_help="Check every file of a build against its checksums.")
def verify(
    build_dir: Annotated[Path, typer.Argument(metavar="DIR", help="A finished build directory.")],
) -> None:
    """Read every file of a build and compare it with the checksums in its manifest.

    Opening a build (stats, export, show, aigem) checks the manifest's own checksum, every
    file's size, every array's shape and a sampled digest of every file (the whole of a file up
    to 8 MiB); verify also reads every byte, and names every file the manifest does not list and
    every symbolic link. One line per problem, exit 1.
    """
    from ngsim_graphs.build import verify_build

    with exit_on_error(), progress_bar() as progress:
        result = verify_build(build_dir, progress)
    for problem in result.problems:
        print_error(problem)
    if result.problems:
        raise typer.Exit(1)
    stdout.print(
        f"{build_dir}: all {counted(result.files, 'file')} match the manifest ({result.bytes / 1e6:,.1f} MB read)."
    )


def _sample_ids(text: str, available: int) -> np.ndarray:
    """'START:END' (END excluded) or '3,7,9' into sample ids, checked against the split's size."""
    try:
        if ":" in text:
            first, _, last = text.partition(":")
            ids = np.arange(int(first or 0), int(last) if last else available)
        else:
            ids = np.array([int(part) for part in text.split(",") if part.strip()])
    except ValueError:
        raise usage_error(f"--samples {text!r}: give START:END or a comma-separated list") from None
    if len(ids) == 0 or ids.min() < 0 or ids.max() >= available:
        raise usage_error(f"--samples {text!r}: the split has samples 0..{available - 1}")
    return ids


@app.command(short_help="Write chosen samples' graphs as explicit Parquet tables.")
def export(
    build_dir: Annotated[Path, typer.Argument(metavar="DIR", help="A finished build directory.")],
    out: Annotated[
        Path, typer.Option("--out", help="Folder for the Parquet tables: new or empty (created).")
    ],
    split: Annotated[Split, typer.Option(help="Split of the samples.")] = Split.TEST,
    samples: Annotated[
        str, typer.Option(help="Sample ids: START:END (END excluded) or 3,7,9.")
    ] = "0:100",
    overwrite: Annotated[
        bool, typer.Option(help="Replace an earlier export (a folder holding only its tables).")
    ] = False,
) -> None:
    """Write chosen samples' graphs as explicit Parquet tables with sample-local node indices.

    The build stores graphs compactly (grid nodes and proximity pairs once per step); this writes
    nodes, spatial_edges, temporal_edges, targets and samples tables for the chosen samples.
    --out must be new or empty, or (with --overwrite) hold only an earlier export as it wrote it
    (export.json lists its tables' checksums); a folder holding anything else is refused. The
    tables land together when all are written.
    """
    from ngsim_graphs.export import check_export_target, graph_tables, write_tables

    with exit_on_interrupt(f"nothing written ({out} is as it was)"), exit_on_error():
        check_export_target(out, overwrite)  # before the work, not only after it
        opened = open_build(build_dir)
        ids = _sample_ids(samples, int(opened.manifest.splits[split.value]))
        tables = graph_tables(opened.graphs(split.value, ids), ids)
        tables["samples"] = opened.samples(split.value).filter(
            pl.col("sample_id").is_in(ids.tolist())
        )
        paths = write_tables(tables, out, overwrite)
    for path, table in zip(paths, tables.values(), strict=True):
        stdout.print(f"{path}  {counted(table.height, 'row')}")


app.command(short_help="Draw samples' graphs in the road frame as a PNG.")(show)
app.command("export-cslstm", short_help="Write CS-LSTM's TrainSet/ValSet/TestSet.mat files.")(
    export_cslstm
)


def main() -> None:
    app()


if __name__ == "__main__":
    main()
