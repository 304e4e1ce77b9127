"""The synthetic data behind `ngsim-graphs synth`: road sections, a camera, traffic, file formats."""
