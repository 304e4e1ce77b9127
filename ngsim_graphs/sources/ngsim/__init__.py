"""NGSIM US-101 and I-80: the three file formats, the six recordings, cleaning and the 0.2 s grid."""
