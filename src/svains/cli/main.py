"""Entry point ``svains``: one sub-command per module in ``svains.cli``.

Each command module defines ``register(app: typer.Typer) -> None``. Modules are imported when the
CLI starts, so the library itself never imports typer.
"""

from __future__ import annotations

import importlib
import logging

import typer

from svains.cli._common import OneLineErrorGroup
from svains.threads import DEFAULT_THREADS, ENV_VAR, limit_threads

# One line per sub-command module, in the order ``svains --help`` lists them.
COMMAND_MODULES: list[str] = [
    "info",
    "run",
    "evaluate",
    "convert",
    "plot",
    "view",
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
    cls=OneLineErrorGroup,
)


@app.callback()
def _root(
    ctx: typer.Context,
    verbose: bool = typer.Option(False, "--verbose", "-v", help="Log at DEBUG level."),
    threads: int = typer.Option(
        DEFAULT_THREADS, "--threads", envvar=ENV_VAR, min=0,
        help="Threads per numerical library (BLAS, OpenMP, OpenCV); 0 keeps their defaults. "
        "The filter's matrices are small, and more threads oversubscribe a shared machine.",
    ),
) -> None:
    logging.basicConfig(
        level=logging.DEBUG if verbose else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )
    # Entered before any command imports numpy, OpenCV or scipy; left when the command ends.
    ctx.with_resource(limit_threads(threads))


for _name in COMMAND_MODULES:
    importlib.import_module(f"svains.cli.{_name}").register(app)


def main() -> None:
    app()


if __name__ == "__main__":  # python -m svains.cli.main
    main()
