"""`aigem`: train and evaluate the AiGem trajectory predictor on a graph dataset build."""

from __future__ import annotations

import typer

app = typer.Typer(
    help="AiGem trajectory prediction: `fit` and `evaluate` arrive with the training work.",
    no_args_is_help=True,
    add_completion=False,
)


@app.callback(invoke_without_command=True)
def root() -> None:
    """AiGem (GAT + linear encoder, GRU decoder, MLP output) on ngsim-graphs builds."""


def main() -> None:
    app()
