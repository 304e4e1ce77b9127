"""`ngsim-graphs synth`: simulated NGSIM- or highD-format files, SynthConfig from the options
(ngsim_graphs.synth does the work); the files written and their sizes printed."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ngsim_cli.command_line import checked_config
from ngsim_cli.console import stdout
from ngsim_cli.exits import exit_on_error, exit_on_interrupt
from ngsim_cli.progress import progress_bar
from ngsim_graphs.config import SynthConfig
from ngsim_graphs.schema import RawFormat


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
    config = checked_config(
        SynthConfig,
        {"raw_format": "--format"},
        raw_format=raw_format,
        recordings=recordings,
        minutes=minutes,
        seed=seed,
        quirks=quirks,
    )
    with exit_on_interrupt(f"nothing written ({out_dir} is as it was)"):
        from ngsim_graphs.synth.folder import period_note  # only when used
        from ngsim_graphs.synth.formats import write_synthetic

        with exit_on_error(), progress_bar() as progress:
            paths = write_synthetic(out_dir, config, lambda what: progress(what, 0, 0))
    for path in paths:
        stdout.print(f"{path}  {path.stat().st_size / 1e6:.1f} MB")
    if note := period_note(config):
        stdout.print(f"Note: {note}.")
