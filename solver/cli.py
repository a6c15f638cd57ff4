"""The ``pba`` command line.

Subcommands live in small modules, each exposing ``register(subparsers)`` which adds its
parsers and sets ``func`` on them. The solver's own commands come first; the service's
(``serve``, ``worker``, ``admin``) are added when the ``service`` package is installed, so the
solver library never imports web code.
"""

from __future__ import annotations

import argparse
import importlib
import sys

SUBCOMMAND_MODULES = (
    "solver.commands",  # run, models, compare, validate
    "solver.simulate.cli",  # simulate
    "service.cli",  # serve, worker, admin
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pba", description="Pushbroom bundle adjustment: orientation of linear-array images"
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in SUBCOMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name and name.startswith(exc.name):
                continue  # optional part not installed
            raise
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
