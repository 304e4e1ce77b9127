"""`ngsim-graphs`: synthesize NGSIM-format data, build graph datasets, and inspect a build."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from ngsim_cli.console import exit_on_input_error, progress_bar, stderr
from ngsim_graphs.building import BuildResult, run_build
from ngsim_graphs.config import BuildConfig, SynthConfig
from ngsim_graphs.layout import read_manifest
from ngsim_graphs.schema import RawFormat

app = typer.Typer(
    help="NGSIM US-101 / I-80 trajectories to spatial-temporal graph datasets.",
    no_args_is_help=True,
    add_completion=False,
)
stdout = Console()


def _config_or_exit(factory, **kwargs):  # type: ignore[no-untyped-def]
    """The config dataclass, or one line on stderr and exit status 2 for an invalid option."""
    try:
        return factory(**kwargs)
    except ValueError as err:
        stderr.print(f"error: {err}", markup=False, highlight=False, soft_wrap=True)
        raise typer.Exit(2) from None


@app.command()
def synth(
    out_dir: Annotated[Path, typer.Argument(help="Folder to write the files into.")],
    raw_format: Annotated[
        RawFormat, typer.Option("--format", help="portal: one combined CSV; csv/txt: one file per period.")
    ] = RawFormat.TXT,
    recordings: Annotated[int, typer.Option(help="How many of the six NGSIM periods (1-6).")] = 6,
    minutes: Annotated[float, typer.Option(help="Length of each recording, minutes.")] = 15.0,
    seed: Annotated[int, typer.Option(help="Random seed; the same seed gives the same bytes.")] = 0,
    quirks: Annotated[
        bool, typer.Option(help="Inject the quirks of real exports (BOM, CRLF, \"1,156\", duplicates, gaps, ...).")
    ] = False,
) -> None:
    """Write synthetic NGSIM-shaped trajectories (simulated traffic, NOT real NGSIM data)."""
    from ngsim_graphs.synthesis import write_synthetic  # the simulator loads only when used

    config = _config_or_exit(
        SynthConfig, raw_format=raw_format, recordings=recordings, minutes=minutes, seed=seed, quirks=quirks
    )
    with progress_bar() as progress:
        paths = write_synthetic(out_dir, config, lambda what: progress(what, 0, 0))
    for path in paths:
        stdout.print(f"{path}  {path.stat().st_size / 1e6:.1f} MB")


def _summary_table(result: BuildResult) -> Table:
    table = Table(title=f"build {result.out_dir}")
    table.add_column("location", no_wrap=True)
    table.add_column("period", no_wrap=True)
    for column in ("rows", "dups", "conflicts", "gaps", "tracks", "grid rows"):
        table.add_column(column, justify="right")
    for r in result.recordings:
        table.add_row(
            r.location,
            r.period,
            *(f"{v:,}" for v in (r.rows, r.exact_duplicates, r.conflicting_duplicates, r.gaps, r.tracks, r.grid_rows)),
        )
    return table


@app.command()
def build(
    raw_paths: Annotated[list[Path], typer.Argument(help="NGSIM files, or folders to search for them.")],
    out: Annotated[Path, typer.Option("--out", help="Output directory of the build.")],
    locations: Annotated[str, typer.Option(help="Comma-separated locations to keep.")] = "us-101,i-80",
    overwrite: Annotated[bool, typer.Option(help="Replace a non-empty output directory.")] = False,
    min_heading_speed_mps: Annotated[
        float, typer.Option(help="Below this speed the last heading is held, m/s.")
    ] = 2.0,
    heading_smoothing_s: Annotated[
        float, typer.Option(help="Centred moving average of positions before the heading, s.")
    ] = 1.0,
) -> None:
    """Read raw NGSIM files (any of the three formats) and write the cleaned 0.2 s tracks."""
    config = _config_or_exit(
        BuildConfig,
        locations=tuple(name.strip().lower() for name in locations.split(",") if name.strip()),
        min_heading_speed_mps=min_heading_speed_mps,
        heading_smoothing_s=heading_smoothing_s,
    )
    with exit_on_input_error(), progress_bar() as progress:
        result = run_build(raw_paths, out, config, overwrite=overwrite, progress=progress)
    for skipped in result.skipped_files:
        stdout.print(f"skipped (not NGSIM): {skipped}")
    stdout.print(_summary_table(result))
    counts = result.manifest["counts"]
    stdout.print(
        f"{counts['rows_read']:,} rows read, {counts['rows_other_locations']:,} of other locations, "
        f"{counts['rows_missing_values']:,} with empty required fields dropped."
    )


@app.command()
def stats(
    build_dir: Annotated[Path, typer.Argument(help="A finished build directory.")],
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON document, nothing else.")] = False,
) -> None:
    """Summarise a finished build: inputs, recordings, duplicates, tracks."""
    with exit_on_input_error():
        manifest = read_manifest(build_dir)
    if as_json:
        typer.echo(json.dumps({"counts": manifest["counts"], "recordings": manifest["recordings"]}, indent=2))
        return
    table = Table(title=f"{build_dir} ({manifest['stage']} stage)")
    for column in ("recording", "vehicles", "tracks", "rows 0.2 s"):
        table.add_column(column)
    for r in manifest["recordings"]:
        table.add_row(f"{r['location']} {r['period']}", f"{r['vehicles']:,}", f"{r['tracks']:,}", f"{r['grid_rows']:,}")
    stdout.print(table)


def main() -> None:
    app()


if __name__ == "__main__":
    main()
