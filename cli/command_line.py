"""What both programs' command lines share: arguments that must be UTF-8 text, plain help,
`--version`, a command of the other program answered with where it is, and an option's value
refused in one line that names the option (exit status 2)."""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable, Iterator, Mapping
from contextlib import contextmanager
from typing import Any, TypeVar

import typer
from typer.core import TyperGroup

from ngsim_cli.console import print_error, stdout

T = TypeVar("T")


def usage_error(message: str) -> typer.Exit:
    """One line on stderr; the caller raises the returned exit (status 2: a bad option)."""
    print_error(message)
    return typer.Exit(2)


def shown_text(text: str) -> str:
    """`text` as it can be printed: the bytes of a name that is not UTF-8 (which Python passes
    on as lone surrogates) as escapes, 'lat\\xe9'."""
    return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


class TextArguments(TyperGroup):
    """A program's commands, whose arguments must be UTF-8 text: a path named in another
    encoding cannot be opened by Polars nor recorded in a manifest or a run's JSON, so it is one
    line and exit status 2 before any command runs, not a traceback halfway through one."""

    def parse_args(self, ctx: typer.Context, args: list[str]) -> list[str]:
        for arg in args:
            if shown_text(arg) != arg:
                raise usage_error(
                    f"the argument {shown_text(arg)} is not UTF-8 text: builds and runs record "
                    "their paths as text; rename it in UTF-8"
                )
        return super().parse_args(ctx, args)


# Help as plain text wrapped to the terminal, up to 100 columns: the boxed tables of rich's help
# squeeze an option's help into a narrow column next to its names and types.
HELP_SETTINGS = {"rich_markup_mode": None, "context_settings": {"max_content_width": 100}}


def naming_the_other_program(program: str, module: str) -> type[TyperGroup]:
    """A command group of UTF-8 arguments (`TextArguments`) that answers a command of the other
    program (`program`, whose typer app is `module`'s `app`) with where it is: `aigem show` ->
    "No such command 'show': it is `ngsim-graphs show`". The other program is loaded only then."""

    class Group(TextArguments):
        def resolve_command(
            self, ctx: typer.Context, args: list[str]
        ) -> tuple[str | None, Any, list[str]]:
            name = args[0] if args else None
            if name and self.get_command(ctx, name) is None and name in _commands_of(module):
                ctx.fail(f"No such command {name!r}: it is `{program} {name}`.")
            return super().resolve_command(ctx, args)

    return Group


def _commands_of(module: str) -> list[str]:
    """The command names of `module`'s typer app."""
    import importlib

    app = importlib.import_module(module).app
    return [
        info.name or info.callback.__name__.replace("_", "-") for info in app.registered_commands
    ]


def add_version_option(app: typer.Typer, program: str, version: str) -> None:
    """Give `app` an eager `--version` that prints `program version` and exits 0."""

    def show(value: bool) -> None:
        if value:
            stdout.print(f"{program} {version}", markup=False, highlight=False)
            raise typer.Exit(0)

    # A default, not an Annotated hint: the hint would name `show`, a local that typer cannot see
    # when it evaluates the (postponed) annotations.
    def options(
        version: bool = typer.Option(
            False,
            "--version",
            help="Print the program's version and exit.",
            callback=show,
            is_eager=True,
        ),
    ) -> None:
        pass

    options.__doc__ = app.info.help
    app.callback()(options)


def option_names(fields: Iterable[str], renamed: Mapping[str, str] | None = None) -> dict[str, str]:
    """Each config field's option: `--` and the field with hyphens (batch_size -> --batch-size),
    unless `renamed` says otherwise (patience_epochs -> --patience)."""
    renamed = renamed or {}
    return {field: renamed.get(field, "--" + field.replace("_", "-")) for field in fields}


def in_option_words(message: str, options: Mapping[str, str]) -> str:
    """A config's error as the command line says it: each field of `options` replaced by its
    option ("batch_size must be >= 1" -> "--batch-size must be >= 1"). A field with an underscore
    is replaced wherever it stands; a field of one word (epochs, split, seed) is also a plain
    word, so only where a setting is named: before " must ", or before its value and "->", ","
    or ":" ("seed 3 -> 4", "split time, ...")."""
    joined = sorted((name for name in options if "_" in name), key=len, reverse=True)
    single = [name for name in options if "_" not in name]
    words = lambda names: r"(?<![\w-])(" + "|".join(map(re.escape, names)) + r")\b"
    patterns = [words(joined)] if joined else []
    if single:
        patterns.append(words(single) + r"(?= must | \S+ -> | [^\s,:]+[,:])")
    if not patterns:
        return message
    return re.sub("|".join(patterns), lambda m: options[m.group(1) or m.group(2)], message)


def checked_config(factory: Callable[..., T], renamed: Mapping[str, str], /, **settings: Any) -> T:
    """`factory(**settings)` (a config dataclass), or one line naming the option of the setting
    it refuses (the field with hyphens, or as `renamed` names it) and exit status 2."""
    with option_values(option_names(settings, renamed)):
        return factory(**settings)


@contextmanager
def option_values(options: Mapping[str, str] | None = None) -> Iterator[None]:
    """A value the block refuses (a config's ValueError, or ngsim_graphs.config's checks) as one
    line naming the option (in_option_words: `options` maps each field to its option) and exit
    status 2. Every option's range is checked so, never by typer's `min=`, whose error is a box
    of four lines."""
    try:
        yield
    except ValueError as err:
        raise usage_error(in_option_words(str(err), options or {})) from None
