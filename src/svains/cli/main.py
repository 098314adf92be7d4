"""Entry point ``svains``: one sub-command per module in ``svains.cli``.

Each command module defines ``register(app: typer.Typer) -> None``. Modules are imported when the
CLI starts, so the library itself never imports typer.
"""

from __future__ import annotations

import importlib
import logging

import typer

# One line per sub-command module, in the order ``svains --help`` lists them.
COMMAND_MODULES: list[str] = [
    "info",
    "run",
    "evaluate",
    "compare",
    "frontend",
    "simulate",
    "demo",
    "batch",
]

app = typer.Typer(
    name="svains",
    help="Tightly-coupled stereo vision-aided inertial navigation (Asadi & Bottasso 2014).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


@app.callback()
def _root(
    verbose: bool = typer.Option(False, "--verbose", "-v", help="Log at DEBUG level."),
) -> None:
    logging.basicConfig(
        level=logging.DEBUG if verbose else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )


for _name in COMMAND_MODULES:
    importlib.import_module(f"svains.cli.{_name}").register(app)


def main() -> None:
    app()
