"""The published rows (aigem.evaluation.results.PAPER_TABLE, then constant velocity's) as figures draw
them: hollow markers in their models' colours (ngsim_graphs.palette), one marker per model."""

from __future__ import annotations

import numpy as np
from matplotlib.axes import Axes

from aigem.evaluation.results import PAPER_TABLE, PUBLISHED_CONSTANT_VELOCITY
from ngsim_graphs.palette import MODEL_COLOURS, PUBLISHED

PUBLISHED_MARKERS = {  # each published row's model (results.PAPER_TABLE, then constant velocity)
    "CS-LSTM": "s",
    "GRIP++": "v",
    "STA-LSTM": "P",
    "DeepTrack": "X",
    "GSTCN": "^",
    "AiGem": "o",
    "constant velocity": "o",
}
PUBLISHED_WORDS = "published, NGSIM"  # after a published row's model, in every legend


def published_style(name: str) -> tuple[str, str, str]:
    """A published row's model ("AiGem" of "AiGem (paper)"), its colour (ngsim_graphs.palette)
    and its marker, drawn hollow."""
    model = name.split(" (")[0]
    return model, MODEL_COLOURS.get(model, PUBLISHED), PUBLISHED_MARKERS[model]


def paper_points(axes: Axes, key: str, last_s: float = 5.0) -> None:
    """The published rows as hollow markers, up to `last_s` seconds: RMSE at 1..5 s (key
    "rmse_m"), or FDE at 5 s ("fde_m"); a row without the number is left out. Labelled by model
    alone, so that the two panels of error_by_horizon share their legend entries. Also
    aigem.paper.report_plots' RMSE figure."""
    for name, row in {**PAPER_TABLE, **PUBLISHED_CONSTANT_VELOCITY}.items():
        model, colour, marker = published_style(name)
        values = row[key] if key == "rmse_m" else (row[key],)
        times = np.arange(1, 6) if key == "rmse_m" else np.array([5.0])
        shown = [
            (t, v) for t, v in zip(times, values, strict=True) if v is not None and t <= last_s
        ]
        if not shown:
            continue
        axes.plot(
            *zip(*shown, strict=True),
            ls="none",
            marker=marker,
            ms=7,
            mfc="none",
            mec=colour,
            mew=1.5,
            clip_on=False,  # a point on the axis' last second is drawn whole
            label=f"{model} ({PUBLISHED_WORDS})",
        )
