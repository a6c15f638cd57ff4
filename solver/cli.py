"""The ``pba`` command line.

Subcommands live in small modules, each exposing ``register(subparsers)`` which adds its
parsers and sets ``func`` on them. The solver's own commands are plain imports. The service's
(``serve``, ``worker``, ``admin``, ``db``) are looked up by name: the solver never imports the
service (an import-linter contract, docs/architecture.md), and a solver-only installation has
no ``service`` package, so that one lookup stays dynamic.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from solver import commands
from solver.gis import cli as gis_cli
from solver.importers import cli as importers_cli
from solver.simulate import cli as simulate_cli

SERVICE_COMMANDS = "service.cli"  # serve, worker, admin, db


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pba", description="Pushbroom bundle adjustment: orientation of linear-array images"
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    commands.register(sub)  # run, models, compare, validate, export-camera, warmup
    simulate_cli.register(sub)  # simulate
    importers_cli.register(sub)  # job, job-sources
    gis_cli.register(sub)  # ground-to-image, image-to-ground, export-rpc, export-geojson
    try:
        service = importlib.import_module(SERVICE_COMMANDS)
    except ModuleNotFoundError as exc:
        if not (exc.name and SERVICE_COMMANDS.startswith(exc.name)):
            raise
    else:
        service.register(sub)
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
