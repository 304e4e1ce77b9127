"""`ngsim-graphs show`: samples' graphs drawn in the road frame, with a run's predictions."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from ngsim_cli.console import counted, exit_on_error, stdout, usage_error
from ngsim_graphs.build import open_build
from ngsim_graphs.errors import NgsimInputError, NgsimOutputError
from ngsim_graphs.schema import Split
from ngsim_graphs.synth.marker import SYNTHETIC_LABEL, synthetic_build


def _scene_range(text: str, max_panels: int) -> tuple[int, int]:
    """`--sample` N or START:END (END excluded) -> (START, END); a usage error otherwise."""
    first, colon, last = text.partition(":")
    try:
        start = int(first)
        end = int(last) if colon else start + 1
    except ValueError:
        raise usage_error(f"--sample {text!r}: give N or START:END (END excluded)") from None
    if not 0 <= start < end:
        raise usage_error(f"--sample {text!r}: START:END needs 0 <= START < END")
    if end - start > max_panels:
        raise usage_error(f"--sample {text!r}: at most {max_panels} samples in one picture")
    return start, end


def _show_name(split: str, start: int, end: int, run: Path | None) -> Path:
    """The default --out: show-test-0.png, show-test-0-7.png, show-test-0-7-RUNNAME.png in the
    current folder, named in full (what is said of it says where it is)."""
    samples = f"{start}" if end == start + 1 else f"{start}-{end - 1}"
    name = f"show-{split}-{samples}" + (f"-{run.resolve().name}" if run else "") + ".png"
    return Path.cwd() / name


def show(
    build_dir: Annotated[Path, typer.Argument(metavar="DIR", help="A finished build directory.")],
    split: Annotated[Split, typer.Option(help="Split of the samples.")] = Split.TEST,
    sample: Annotated[
        str,
        typer.Option(
            metavar="N|START:END", help="Sample id, or ids START..END-1: one panel each (<= 64)."
        ),
    ] = "0",
    out: Annotated[
        Path | None,
        typer.Option(
            "--out",
            help="PNG to write [default: show-SPLIT-SAMPLES.png here, -RUN added with --run].",
        ),
    ] = None,
    run: Annotated[
        Path | None,
        typer.Option(
            "--run",
            help="An aigem run of this build: also draw its predictions and constant "
            "velocity's (a multi-horizon run's longest-horizon model).",
        ),
    ] = None,
    columns: Annotated[int, typer.Option(min=1, help="Panels per row.")] = 4,
    overwrite: Annotated[bool, typer.Option(help="Replace --out if it exists.")] = False,
) -> None:
    """Draw samples' graphs as one PNG, a panel per sample, in the sample frame (x lateral, y
    along the road, the ego at (0, 0) at the present step, metres): history nodes (older:
    fainter), temporal edges as each vehicle's history, the present step's spatial edges, the
    d_sense circle, and the targets' recorded futures.
    """
    from ngsim_graphs.scenes import MAX_PANELS, scene_titles, write_scenes  # loads matplotlib

    start, end = _scene_range(sample, MAX_PANELS)
    out = out if out is not None else _show_name(split.value, start, end, run)
    with exit_on_error():
        if out.exists() and not overwrite:
            raise NgsimOutputError(out, "exists; pass --overwrite to replace it")
        opened = open_build(build_dir)
        size = int(opened.manifest.splits[split.value])
        if size == 0:
            raise NgsimInputError(build_dir, f"its {split.value} split is empty: nothing to draw")
        if end > size:
            raise usage_error(
                f"--sample {sample!r}: the {split.value} split has samples 0..{size - 1}"
            )
        ids = np.arange(start, end)
        predictions = None
        if run is None:
            batch = opened.graphs(split.value, ids)
        else:
            from aigem.prediction import predict_samples  # torch loads only when asked

            batch, predictions = predict_samples(run, build_dir, split, ids)
        titles = scene_titles(opened.samples(split.value), split.value, ids)
        synthetic = synthetic_build(opened.manifest)
        scenes = write_scenes(
            out, batch, titles, opened.config.d_sense_m, predictions, columns, overwrite, synthetic
        )
    what = f"sample {start}" if end == start + 1 else f"samples {start}..{end - 1}"
    drawn = f"{counted(sum(s.nodes for s in scenes), 'node')}, {counted(sum(s.targets for s in scenes), 'target')}"
    also = f"; dashed: {' and '.join(predictions)} of {run}" if predictions else ""
    kind = f"; {SYNTHETIC_LABEL}" if synthetic else ""
    stdout.print(
        f"wrote {out}: {split.value} {what} of {build_dir} ({drawn}){also}{kind}",
        markup=False,
        highlight=False,
        soft_wrap=True,
    )
