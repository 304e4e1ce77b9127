"""What `aigem evaluate --plots DIR` writes: the figures of aigem.figures.plots, and a grid of scenes.

    DIR/error_by_horizon.png          RMSE and mean displacement error at every 0.2 s step
    DIR/error_by_region.png           the same for front, mid and rear actors
    DIR/final_error_distribution.png  ECDF of each target's final displacement error
    DIR/scenes.png                    the worst, median and best targets by AiGem's final error,
                                      each followed in its scene

    DIR/plots.json                    which files of DIR are ours to replace

DIR is created. `plots.json` says which files are ours (ngsim_graphs.plot_folder, the rule
`ngsim-graphs stats --plots` follows too): a file of these names that it does not list (a
picture of someone else's) is never replaced, the call stops with an error naming it before
anything is written. Every picture is drawn before the first is written, so a failure (a model
that cannot be loaded, non-finite predictions) leaves DIR as it was; each is written under a
temporary name and renamed; a picture of an earlier call that this call does not draw
(scenes.png, with --other-build) is removed, so DIR never mixes two evaluations.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from aigem.evaluation.evaluate import target_choice
from aigem.evaluation.followed import final_errors_m, followed_words, matched_target
from aigem.evaluation.results import Evaluation
from aigem.figure_parts import png_bytes
from aigem.figures.plots import error_by_horizon, error_by_region, final_error_distribution
from ngsim_graphs.build import OpenBuild, open_build
from ngsim_graphs.graphs import GraphBatch
from ngsim_graphs.plot_folder import OWNED, claim_plot_folder, land_plots  # noqa: F401 (OWNED too)
from ngsim_graphs.synth.marker import SYNTHETIC_LABEL, synthetic_build

FIGURES = {
    "error_by_horizon": error_by_horizon,
    "error_by_region": error_by_region,
    "final_error_distribution": final_error_distribution,
}
SCENES = "scenes.png"
SCENE_GROUPS = ("worst", "median", "best")
PICTURES = (*(f"{name}.png" for name in FIGURES), SCENES)
WRITER = "aigem evaluate --plots"


def describe_build(build_dir: str | Path) -> str:
    """Where our numbers come from, for a figure: the build's folder, its recordings, and whether
    its inputs were written by `ngsim-graphs synth` (synth's marker lists them)."""
    build = open_build(Path(build_dir))
    entries = build.entries
    locations = ", ".join(sorted({entry.location for entry in entries}))
    kind = (
        SYNTHETIC_LABEL
        if synthetic_build(build.manifest)
        else f"{build.manifest.dataset}-format inputs without synth's marker"
    )
    plural = "s" if len(entries) != 1 else ""
    name = Path(build_dir).resolve().name  # the folder, not a path of this machine
    return f'build folder "{name}": {len(entries)} recording{plural} of {locations}, {kind}'


def scene_grid(
    result: Evaluation,
    run_dir: Path,
    device_choice: str = "cpu",
    per_group: int = 3,
) -> bytes | None:
    """A PNG: a row each of the worst, median and best `per_group` targets of the evaluated
    split by AiGem's final displacement error (evaluate.target_choice, each in its own
    scene), each followed in its scene: its history, recorded future, and the predictions of
    AiGem (the run's longest-horizon model) and constant velocity, the rest of the scene faded.
    None, drawing nothing, where no target is valid at the last step or the evaluation was on
    another build than the run's (its predictions are drawn on its own build only)."""
    from aigem.evaluation.prediction import (
        MODEL_LABEL,
        predict_samples,
    )  # the model, only when drawing
    from ngsim_graphs.scenes import DPI as SCENE_DPI
    from ngsim_graphs.scenes import scene_figure

    final = result.final
    if not result.same_build or final is None or not len(final.sample):
        return None
    chosen = target_choice(final.sample, final.model_m, per_group)
    picked = np.concatenate([chosen[group] for group in SCENE_GROUPS])
    batch, predictions = predict_samples(
        run_dir, Path(result.build_dir), result.split, final.sample[picked], device_choice
    )
    errors = final_errors_m(batch, predictions)
    follow = [
        matched_target(batch, b, errors[MODEL_LABEL], final.model_m[index])
        for b, index in enumerate(picked)
    ]
    build = open_build(Path(result.build_dir))
    horizon_s = result.horizon_steps * result.time_step_s
    figure, _ = scene_figure(
        batch,
        _scene_titles(result, build, batch, chosen, follow, errors),
        build.config.d_sense_m,
        predictions,
        per_group,
        result.synthetic,
        follow=follow,
        title=f"The worst, median and best targets of the {result.split} split by AiGem's "
        f"final error at {horizon_s:g} s, each followed in its scene",
    )
    return png_bytes(figure, dpi=SCENE_DPI)


def _scene_titles(
    result: Evaluation,
    build: OpenBuild,
    batch: GraphBatch,
    chosen: dict[str, np.ndarray],
    follow: list[int],
    errors: dict[str, np.ndarray],
) -> list[str]:
    """Each panel's title: its group and rank, the target's vehicle and both final errors, the
    scene it is in."""
    from ngsim_graphs.scenes import scene_titles, vehicle_ids

    ids = result.final.sample[np.concatenate([chosen[group] for group in SCENE_GROUPS])]
    scenes = scene_titles(build.samples(result.split), result.split, ids)
    tracks = batch.node_track[batch.target_node[follow]]
    vehicles = vehicle_ids(build.tracks(), tracks)
    horizon_s = result.horizon_steps * result.time_step_s
    places = [(group, rank + 1) for group in SCENE_GROUPS for rank in range(len(chosen[group]))]
    return [
        f"{group} {rank}: {followed_words(target, vehicles[int(track)], errors, horizon_s)}\n"
        f"in {scene}"
        for (group, rank), target, track, scene in zip(places, follow, tracks, scenes, strict=True)
    ]


def write_evaluation_plots(
    result: Evaluation,
    folder: Path,
    run_dir: Path | None = None,
    device_choice: str = "cpu",
) -> list[Path]:
    """Write the FIGURES as `<name>.png` into `folder` (created), and, given the evaluated
    `run_dir`, the scene grid (scene_grid); returns the paths written. See the module's
    docstring for what is replaced and what is refused."""
    owned = claim_plot_folder(folder, PICTURES, WRITER)
    label = describe_build(result.build_dir)
    pictures = {f"{name}.png": png_bytes(draw(result, label)) for name, draw in FIGURES.items()}
    scenes = scene_grid(result, run_dir, device_choice) if run_dir is not None else None
    if scenes is not None:
        pictures[SCENES] = scenes
    return land_plots(folder, pictures, owned, WRITER)
