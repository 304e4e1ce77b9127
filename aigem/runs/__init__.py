"""A run's folder and records: its file names, run.json and horizons.json (records), the build it
was trained on (provenance), metrics.jsonl and baseline.json (run_log; constant velocity's
losses: baseline), the checkpoints and the models loaded from them (checkpoints), what a fit
refuses (refusals, unfinished), a fit's course in its folder (course, folder) and curves.png
(curves).

Reads and writes a run, trains nothing: it imports the model wing and aigem's top, no wing above.
"""
