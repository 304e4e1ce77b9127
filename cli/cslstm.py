"""`ngsim-graphs export-cslstm`: CS-LSTM's TrainSet.mat / ValSet.mat / TestSet.mat."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from ngsim_cli.console import counted, print_table, stdout
from ngsim_cli.exits import exit_on_error, exit_on_interrupt
from ngsim_cli.progress import progress_bar
from ngsim_graphs.cslstm import SPLIT_NAMES as SPLITS


def _summary(result) -> Table:  # type: ignore[no-untyped-def]
    table = Table(title=f"export-cslstm {result.out}")
    table.add_column("id", justify="right")
    table.add_column("recording", no_wrap=True)
    for column in ("rows", "vehicles", *(f"traj {s}" for s in SPLITS), "short vehicles"):
        table.add_column(column, justify="right")
    for d in result.datasets:
        table.add_row(
            str(d.dataset_id),
            d.recording,
            f"{d.rows:,}",
            f"{d.vehicles:,}",
            *(f"{d.kept_rows[s]:,}" for s in SPLITS),
            f"{d.short_vehicles:,} ({counted(d.short_vehicle_rows, 'row')})",
        )
    return table


def _dropped_lines(result) -> list[str]:  # type: ignore[no-untyped-def]
    lines = []
    for report in result.inputs:
        if report.rows_missing_values:
            lines.append(
                f"{report.path}: {counted(report.rows_missing_values, 'row')} with an empty Vehicle_ID, "
                "Frame_ID, Global_Time, Local_X, Local_Y or Lane_ID left out, the first at line "
                f"{report.first_missing_line}"
            )
        if report.rows_stray:
            lines.append(
                f"{report.path}: {counted(report.rows_stray, 'row')} whose Global_Time fits none of its "
                f"recordings left out, the first at line {report.first_stray_line}"
            )
        if report.rows_other_locations:
            lines.append(
                f"{report.path}: {counted(report.rows_other_locations, 'row')} of other locations skipped"
            )
    return lines


def export_cslstm(
    raw_paths: Annotated[
        list[Path],
        # Said in the docstring: typer would show its type as "<list[Path]>".
        typer.Argument(metavar="RAW_PATH", hidden=True),
    ],
    out: Annotated[
        Path,
        typer.Option(
            "--out",
            help="Folder for the three .mat files: new or empty (or an earlier export); it is "
            "written aside and put in place whole.",
        ),
    ],
    allow_partial: Annotated[
        bool,
        typer.Option(
            help="Write the recordings present when some of the six are missing (dataset ids "
            "unchanged); without it a missing recording is an error."
        ),
    ] = False,
    overwrite: Annotated[
        bool,
        typer.Option(
            help="Replace an earlier export in --out: only one whose files are still those its "
            "cslstm-export.json lists (their sha256), nothing else beside them."
        ),
    ] = False,
) -> None:
    """Write TrainSet.mat, ValSet.mat and TestSet.mat as CS-LSTM's preprocess_data.m makes them.

    RAW_PATH...: the six US-101 and I-80 recordings: files of any of the three NGSIM formats (the
    portal CSV too), or folders to search for them.

    The literature's dataset (CS-LSTM, and every model compared on its files): each recording's
    raw rows, uncleaned, in the script's order; per row the lateral and longitudinal maneuver
    classes and the 39-cell neighbour grid; the vehicle-id split 70/10/20; the edge filter (3 s of
    history, more than 0.1 s of future). Single precision, feet, quirks kept (docs/cslstm.md).
    Read the files with scipy.io.loadmat, as CS-LSTM's ngsimDataset does. A vehicle of under 31
    rows, where the script would stop, has no rows in traj; they are counted.
    """
    from ngsim_graphs.cslstm_export import FILE_NAMES, MARKER
    from ngsim_graphs.cslstm_export import export_cslstm as export

    left = f"nothing written ({out} is as it was)"
    with exit_on_interrupt(left), exit_on_error(), progress_bar() as progress:
        result = export(
            raw_paths, out, allow_partial=allow_partial, overwrite=overwrite, progress=progress
        )
    for skipped in result.skipped_files:
        stdout.print(f"skipped (not NGSIM): {skipped}", markup=False, highlight=False)
    print_table(_summary(result))
    for line in _dropped_lines(result):
        stdout.print(line, markup=False, highlight=False, soft_wrap=True)
    if result.missing:
        stdout.print(
            f"missing (--allow-partial): {', '.join(result.missing)}", markup=False, highlight=False
        )
    for split in SPLITS:
        path = out / FILE_NAMES[split]
        stdout.print(
            f"{path}: traj {result.rows[split]:,} x 47, tracks 6 x {result.tracks_width[split]:,} "
            f"({path.stat().st_size / 2**20:,.1f} MiB)",
            markup=False,
            highlight=False,
            soft_wrap=True,
        )
    stdout.print(f"{out / MARKER}: the inputs, their checksums and these counts.", markup=False)
