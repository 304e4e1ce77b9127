"""ngsim-graphs: NGSIM US-101 and I-80 trajectories to spatial-temporal graph datasets."""

__version__ = "0.1.0"
