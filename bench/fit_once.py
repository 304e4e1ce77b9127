"""One epoch of a multi-horizon fit by whichever aigem is first on the path, timed.

`bench_fit_loop.py` runs this file in a fresh process per fit, with PYTHONPATH set to a checkout
of REV or of this tree, so that two checkouts are timed alike on one build: it uses only what
every checkout since 66e4b70 has (`aigem.fit_horizons`, `TrainConfig(epochs, batch_size, seed,
threads, workers)`, each model's metrics.jsonl and last.pt). Prints one JSON line on stdout: the
training loop's graphs/s (fit's own figure), each model's first-epoch losses and a digest of the
models' weights (the same numbers from both checkouts: the same training).

    PYTHONPATH=CHECKOUT python bench/fit_once.py BUILD [--horizons-s 1,2,3,4,5] [--batch-size 32]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import tempfile
from pathlib import Path

import torch

import aigem
from aigem import ModelConfig, TrainConfig


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("build", type=Path)
    parser.add_argument("--horizons-s", default="1,2,3,4,5")
    parser.add_argument("--batch-size", type=int, default=32)
    args = parser.parse_args()
    horizons_s = tuple(float(h) for h in args.horizons_s.split(","))
    train = TrainConfig(epochs=1, batch_size=args.batch_size, seed=0, threads=1, workers=0)
    digest = hashlib.sha256()
    with tempfile.TemporaryDirectory() as tmp:
        results = aigem.fit_horizons(
            args.build, Path(tmp) / "run", horizons_s, ModelConfig(), train, "cpu"
        )
        rows = []
        for result in results:
            last = torch.load(result.run_dir / "last.pt", map_location="cpu", weights_only=True)
            for name in sorted(last["model"]):
                digest.update(last["model"][name].numpy().tobytes())
            first = (result.run_dir / "metrics.jsonl").read_text().splitlines()[0]
            rows.append(json.loads(first))
    figures = {
        "code": str(Path(aigem.__file__).parent.parent),
        "graphs_per_s": results[0].train_graphs_per_s,
        "val_loss_m2": [row["val_loss_m2"] for row in rows],
        "weights": digest.hexdigest()[:16],
    }
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
