"""The ``pba`` command line.

Subcommands live in small modules, each exposing ``register(subparsers)`` which adds its
parsers and sets ``func`` on them; :func:`build_parser` imports and calls them, one line each.
The solver never imports the service (an import-linter contract, docs/architecture.md): the
installed ``pba`` console script is :func:`service.cli.main`, which passes the server's
commands (``serve``, ``worker``, ``admin``, ``db``) in as ``extra`` registrars.
``python -m solver.cli`` is the solver's commands alone.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence

from solver import commands
from solver.gis import results_cli
from solver.importers import job_cli
from solver.importers import rpc_cli as import_rpc_cli
from solver.importers import sensor_cli as import_sensor_cli
from solver.matching import match_cli
from solver.simulate import simulate_cli

Registrar = Callable[[argparse._SubParsersAction], None]


def build_parser(extra: Sequence[Registrar] = ()) -> argparse.ArgumentParser:
    """The ``pba`` parser: the solver's commands, then those of ``extra`` (the server's)."""
    parser = argparse.ArgumentParser(
        prog="pba", description="Pushbroom bundle adjustment: orientation of linear-array images"
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    commands.register(sub)  # run, models, compare, validate, export-camera, warmup
    simulate_cli.register(sub)  # simulate
    job_cli.register(sub)  # job, job-sources
    import_rpc_cli.register(sub)  # import-rpc
    import_sensor_cli.register(sub)  # import-sensor, simulate-measurements
    results_cli.register(sub)  # ground-to-image, image-to-ground, export-rpc, export-geojson, ortho, resample
    match_cli.register(sub)  # match
    match_cli.register_gcp(sub)  # match-gcp
    for register in extra:
        register(sub)
    return parser


def main(argv: list[str] | None = None, extra: Sequence[Registrar] = ()) -> int:
    """Run one ``pba`` command; its exit status (2 and the help when none is given)."""
    parser = build_parser(extra)
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
