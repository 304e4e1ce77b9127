"""A run's folder and records: run.json, the metrics log, checkpoints, the course of a fit,
the refusals of a run that cannot be trained or scored, constant velocity's baseline.json and
curves.png. Reads and writes a run; trains nothing.
"""
