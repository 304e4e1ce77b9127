"""The colours of the models in every figure of both programs, defined once: AiGem is the same
blue, constant velocity the same orange and a recorded future the same black in the scenes
(`ngsim-graphs show`, `aigem evaluate`'s scenes.png), the error figures (aigem.figures.plots) and
the report's figures (aigem.paper.report_plots). A published row of the literature is drawn as a
hollow marker: the published AiGem in AiGem's colour, the published constant velocity in
constant velocity's, every other published model in PUBLISHED, each its own marker shape."""

from __future__ import annotations

AIGEM = "tab:blue"
CONSTANT_VELOCITY = "tab:orange"
TRUTH = "black"  # a recorded future
PUBLISHED = "0.4"  # a published model other than AiGem and constant velocity
# AiGem at the settings of an ablation other than the paper's (which is drawn in AIGEM).
OTHER_SETTINGS = ("#9ecae1", "#0b3c61", "#6b6b6b")
# AiGem in the front, mid and rear regions: shades of AIGEM, the paper's model in each.
REGION_SHADES = ("#9ecae1", AIGEM, "#0b3c61")
# By the labels that aigem.evaluation.prediction gives its predictions.
MODEL_COLOURS = {"AiGem": AIGEM, "constant velocity": CONSTANT_VELOCITY}
