"""`aigem`: train and evaluate the AiGem trajectory predictor on an ngsim-graphs build."""

from __future__ import annotations

import typer

from aigem import __version__
from ngsim_cli.command_line import HELP_SETTINGS, add_version_option, naming_the_other_program
from ngsim_cli.evaluation import evaluate
from ngsim_cli.fit import fit
from ngsim_cli.paper import paper

app = typer.Typer(
    help="AiGem trajectory prediction (GAT + linear encoder, GRU decoder, MLP output).",
    no_args_is_help=True,
    add_completion=False,
    cls=naming_the_other_program("ngsim-graphs", "ngsim_cli.ngsim"),
    **HELP_SETTINGS,
)


add_version_option(app, "aigem", __version__)

app.command(short_help="Train AiGem on a build (one horizon or the paper's five).")(fit)
app.command(short_help="Score a run against constant velocity and the paper.")(evaluate)
app.command(short_help="The paper's experiments: builds, fits, evaluations, report.")(paper)


def main() -> None:
    app()


if __name__ == "__main__":
    main()
