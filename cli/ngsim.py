"""`ngsim-graphs`: synthesize NGSIM-format data, build graph datasets, and inspect a build."""

from __future__ import annotations

import typer

from ngsim_cli.build import BUILD_HELP, build
from ngsim_cli.command_line import HELP_SETTINGS, add_version_option, naming_the_other_program
from ngsim_cli.cslstm import export_cslstm
from ngsim_cli.inspection import export, stats, verify
from ngsim_cli.show import show
from ngsim_cli.synth import synth
from ngsim_graphs import __version__
from ngsim_graphs.sources.registry import labels_in_words

app = typer.Typer(
    help=f"Vehicle trajectories ({labels_in_words()}) to spatial-temporal graph datasets.",
    no_args_is_help=True,
    add_completion=False,
    cls=naming_the_other_program("aigem", "ngsim_cli.aigem"),
    **HELP_SETTINGS,
)


add_version_option(app, "ngsim-graphs", __version__)


app.command(short_help="Write synthetic NGSIM- or highD-format trajectories.")(synth)
app.command(short_help=f"Build the graph dataset from {labels_in_words()} files.", help=BUILD_HELP)(
    build
)
app.command(short_help="Summarize a build: samples, graph sizes, degrees, plots.")(stats)
app.command(short_help="Check every file of a build against its checksums.")(verify)
app.command(short_help="Write chosen samples' graphs as explicit Parquet tables.")(export)
app.command(short_help="Draw samples' graphs in the road frame as a PNG.")(show)
app.command("export-cslstm", short_help="Write CS-LSTM's TrainSet/ValSet/TestSet.mat files.")(
    export_cslstm
)


def main() -> None:
    app()


if __name__ == "__main__":
    main()
