"""`ngsim-graphs show`: samples' graphs drawn in the road frame, with a run's predictions."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import numpy as np
import typer

from ngsim_cli.command_line import option_values, usage_error
from ngsim_cli.console import counted, stdout
from ngsim_cli.exits import exit_on_error
from ngsim_graphs.build import open_build
from ngsim_graphs.config import check_count
from ngsim_graphs.errors import NgsimInputError, NgsimOutputError
from ngsim_graphs.schema import Split
from ngsim_graphs.synth.marker import SYNTHETIC_LABEL, synthetic_build

if TYPE_CHECKING:
    from ngsim_graphs.scenes import DrawnScene


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


def _described(ids: list[int], every_window: bool) -> str:
    """The samples drawn, for the printed line: `sample 3`, `samples 0..7`, `samples 0, 2, 5
    (one per ego)`."""
    if len(ids) == 1:
        return f"sample {ids[0]}"
    if ids == list(range(ids[0], ids[-1] + 1)):
        return f"samples {ids[0]}..{ids[-1]}" + ("" if every_window else " (one per ego)")
    return f"samples {', '.join(map(str, ids))} (one per ego)"


def _show_name(split: str, ids: list[int], every_window: bool, run: Path | None) -> Path:
    """The default --out, in the current folder, named for what it holds: show-test-2.png (one
    sample), show-test-0-7.png (samples 0..7, --every-window), show-test-egos-0-to-14.png (one
    sample per ego from 0 to 14); -RUNNAME added with --run."""
    if len(ids) == 1:
        samples = f"{ids[0]}"
    elif every_window:
        samples = f"{ids[0]}-{ids[-1]}"
    else:
        samples = f"egos-{ids[0]}-to-{ids[-1]}"
    name = f"show-{split}-{samples}" + (f"-{run.resolve().name}" if run else "") + ".png"
    return Path.cwd() / name


def show(
    build_dir: Annotated[Path, typer.Argument(metavar="DIR", help="A finished build directory.")],
    split: Annotated[Split, typer.Option(help="Split of the samples.")] = Split.TEST,
    sample: Annotated[
        str,
        typer.Option(
            metavar="N|START:END",
            help="Sample id N, or END-START panels (<= 64) from sample START on: the first sample "
            "of each ego, or with --every-window every sample START..END-1.",
        ),
    ] = "0",
    every_window: Annotated[
        bool,
        typer.Option(
            "--every-window",
            help="Draw every sample of START:END, several windows of one ego among them.",
        ),
    ] = False,
    out: Annotated[
        Path | None,
        typer.Option(
            "--out",
            help="PNG to write [default: here, named for the samples drawn: show-SPLIT-N.png, "
            "show-SPLIT-START-LAST.png with --every-window, show-SPLIT-egos-FIRST-to-LAST.png; "
            "-RUN added with --run].",
        ),
    ] = None,
    run: Annotated[
        Path | None,
        typer.Option(
            "--run",
            help="An aigem run of this build: draw one target per panel instead of the "
            "graph (the sample's median by the run's final error), its truth beside the run's "
            "prediction and constant velocity's (a multi-horizon run's longest-horizon model).",
        ),
    ] = None,
    columns: Annotated[int, typer.Option(help="Panels per row.")] = 2,
    overwrite: Annotated[bool, typer.Option(help="Replace --out if it exists.")] = False,
) -> None:
    """Draw samples as one PNG, a panel per sample, in the sample frame seen from above (metres,
    the ego at (0, 0) at the present step; travel to the right, the lateral offset to the left
    of travel upwards). Without --run, each sample's graph in equal metres on both axes:
    history nodes (older: fainter), temporal edges as each vehicle's history, the present
    step's spatial edges, the d_sense circle, the targets' recorded futures. With --run, one
    target per panel, its recorded future beside the predictions, the rest of the scene faded.
    START:END draws one ego per panel: the first sample of each ego from START on (consecutive
    samples are often one ego's windows).
    """
    with option_values({"columns": "--columns"}):
        check_count("columns", columns, 1)
    from ngsim_graphs.scenes import MAX_PANELS, one_per_ego, scene_titles, write_scenes

    start, end = _scene_range(sample, MAX_PANELS)
    with exit_on_error():
        opened = open_build(build_dir)
        size = int(opened.manifest.splits[split.value])
        if size == 0:
            raise NgsimInputError(build_dir, f"its {split.value} split is empty: nothing to draw")
        if end > size:
            raise usage_error(
                f"--sample {sample!r}: the {split.value} split has samples 0..{size - 1}"
            )
        samples = opened.samples(split.value)
        if every_window or end == start + 1:
            ids = np.arange(start, end)
        else:
            ids = np.array(one_per_ego(samples, start, end - start), dtype=np.int64)
        out = out if out is not None else _show_name(split.value, ids.tolist(), every_window, run)
        if out.exists() and not overwrite:
            raise NgsimOutputError(out, "exists; pass --overwrite to replace it")
        titles = scene_titles(samples, split.value, ids)
        predictions, follow = None, None
        if run is None:
            batch = opened.graphs(split.value, ids)
        else:
            from aigem.evaluation.followed import predicted_scenes  # torch loads only when asked

            batch, predictions, follow, words = predicted_scenes(run, build_dir, split.value, ids)
            titles = [f"{title}\n{said}" for title, said in zip(titles, words, strict=True)]
        synthetic = synthetic_build(opened.manifest)
        scenes = write_scenes(
            out,
            batch,
            titles,
            opened.config.d_sense_m,
            predictions,
            columns,
            overwrite,
            synthetic,
            follow,
        )
    _print_written(
        out, split.value, _described(ids.tolist(), every_window), build_dir, scenes, run, synthetic
    )


def _print_written(
    out: Path,
    split: str,
    what: str,
    build_dir: Path,
    scenes: tuple[DrawnScene, ...],
    run: Path | None,
    synthetic: bool,
) -> None:
    """The line that says where the picture went and what it holds."""
    nodes = counted(sum(s.nodes for s in scenes), "node")
    targets = counted(sum(s.targets for s in scenes), "target")
    drawn = f"{nodes}, {targets}"
    also = (
        f"; each panel follows its median target, beside AiGem's and constant velocity's "
        f"predictions of {run}"
        if run is not None
        else ""
    )
    kind = f"; {SYNTHETIC_LABEL}" if synthetic else ""
    stdout.print(
        f"wrote {out}: {split} {what} of {build_dir} ({drawn}){also}{kind}",
        markup=False,
        highlight=False,
        soft_wrap=True,
    )
