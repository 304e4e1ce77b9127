"""ngsim-graphs: NGSIM US-101 and I-80 (and highD) trajectories to spatial-temporal graph datasets.

The names a researcher needs, importable from the package itself:

    from ngsim_graphs import open_build
    build = open_build("demo/build")      # checked, memory-mapped
    batch = build.graphs("test", [0, 1])  # a GraphBatch of two samples' graphs

They are imported on first use (PEP 562), so that `import ngsim_graphs` and the programs' --help
stay fast.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from ngsim_graphs.version import __version__

_EXPORTS = {
    "open_build": "ngsim_graphs.build",
    "OpenBuild": "ngsim_graphs.build",
    "verify_build": "ngsim_graphs.build",
    "BuildConfig": "ngsim_graphs.config",
    "SynthConfig": "ngsim_graphs.config",
    "run_build": "ngsim_graphs.pipeline",
    "GraphBatch": "ngsim_graphs.graphs",
    "MinMaxScaler": "ngsim_graphs.scaling",
    "Manifest": "ngsim_graphs.manifest",
    "Split": "ngsim_graphs.schema",
    "SplitMode": "ngsim_graphs.schema",
    "NgsimError": "ngsim_graphs.errors",
    "NgsimInputError": "ngsim_graphs.errors",
}
__all__ = [
    "__version__",
    "open_build",
    "OpenBuild",
    "verify_build",
    "BuildConfig",
    "SynthConfig",
    "run_build",
    "GraphBatch",
    "MinMaxScaler",
    "Manifest",
    "Split",
    "SplitMode",
    "NgsimError",
    "NgsimInputError",
]

if TYPE_CHECKING:
    from ngsim_graphs.build import OpenBuild, open_build, verify_build
    from ngsim_graphs.config import BuildConfig, SynthConfig
    from ngsim_graphs.errors import NgsimError, NgsimInputError
    from ngsim_graphs.graphs import GraphBatch
    from ngsim_graphs.manifest import Manifest
    from ngsim_graphs.pipeline import run_build
    from ngsim_graphs.scaling import MinMaxScaler
    from ngsim_graphs.schema import Split, SplitMode


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(_EXPORTS[name]), name)


def __dir__() -> list[str]:
    """The public names (__all__), not this module's own imports (importlib, typing's names)."""
    return sorted(__all__)
