"""A finished build looked into, without writing to it: `ngsim-graphs stats` (its samples, graph
sizes and degrees, and histograms), `verify` (every file against its checksum) and `export`
(chosen samples' graphs as explicit Parquet tables)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import numpy as np
import polars as pl
import typer

from ngsim_cli.command_line import option_values, usage_error
from ngsim_cli.console import counted, print_error, print_table, print_warning, stdout
from ngsim_cli.exits import exit_on_error, exit_on_interrupt
from ngsim_cli.progress import progress_bar
from ngsim_cli.stats_view import STATS_TABLES
from ngsim_graphs.build import open_build
from ngsim_graphs.config import check_count, check_seed
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.schema import Split
from ngsim_graphs.statistics import MAX_DEGREE_GRAPHS, build_statistics
from ngsim_graphs.synth.marker import SYNTHETIC_LABEL, synthetic_build, synthetic_inputs_of


def _write_plots(values, folder: Path, synthetic: bool) -> list[Path]:  # type: ignore[no-untyped-def]
    """The PNG histograms (a file of their names that is not ours refused: plot_folder)."""
    from ngsim_graphs.plotting import write_histograms  # matplotlib loads only when plotting

    return write_histograms(values, folder, synthetic)


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
        print_warning(warning)


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
