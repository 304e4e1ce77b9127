"""The names in a folder of `aigem paper` (paper.json, report.json, builds/, runs/, ...), the
marker that says a folder is ours, and the refusal of such a folder where a run is wanted.

Apart from the paper's folder module (aigem.paper.experiments.folder) so that a run's checks and evaluation
can tell a paper folder from a run without the paper's own work: no module here reads a run.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.landing import json_object

PAPER_D_MIN_M = 25.0  # the d_min of the paper's model (the others: the d_min ablation)
PAPER_JSON, REPORT_JSON, REPORT_MD = "paper.json", "report.json", "report.md"
PAPER_LOG = "paper.log"  # `aigem paper`'s stderr lines, each after its time, appended
BUILDS, RUNS, FIGURES = "builds", "runs", "figures"
WRITTEN_BY = "aigem paper"


def build_name(d_min_m: float) -> str:
    return f"dmin-{d_min_m:g}m"


def is_ours(document: dict[str, Any] | None) -> bool:
    """Whether a paper.json document (None: none, or not a JSON object) was written by us."""
    return document is not None and document.get("written_by") == WRITTEN_BY


def refuse_paper_folder_as_run(path: Path) -> None:
    """Refuse a folder of `aigem paper` where a run is wanted (`aigem evaluate`), naming its
    runs: it holds one run per fit and seed under runs/, and its report."""
    if not is_ours(json_object(path / PAPER_JSON)):
        return
    found = sorted(p.name for p in (path / RUNS).iterdir()) if (path / RUNS).is_dir() else []
    paper = build_name(PAPER_D_MIN_M)  # the paper's model's fit is named as its build
    runs = f"its runs are at {path / RUNS}: {', '.join(found)}" if found else "no run yet"
    if paper in found:
        runs += f" (the paper's model: {path / RUNS / paper})"
    raise NgsimInputError(path, f"is an `aigem paper` folder, not a run: {runs}")
