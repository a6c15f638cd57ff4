"""``pba import-sensor METADATA... [--image-id ID]... [-o fragment.json] [--check-rpc]``: vendors'
sensor metadata (Maxar/DigitalGlobe support-data XML, DIMAP v1 of SPOT 1-5, DIMAP v2 of SPOT 6/7
and Pleiades) as a fragment of the job document:
``cameras`` (one per image), ``images`` (ephemeris, attitude samples, first-line time, a default
model) and ``options`` (ephemeris and attitude weights from the file's covariances), as JSON.

On standard error, per image: what was read and how far the job form is from the vendor's
exact model (px); with ``--check-rpc`` also the exact model against the vendor's RPC of the
same image (RMS and maximum px over image positions x heights; a DIMAP v2 product's RPC_*.XML is
looked for beside its DIM_*.XML), or, without an RPC, with the product's own tie points or extent
corners (metres). Exit 0, or 2 with a message
naming the file and the element at fault (docs/sensor-metadata.md).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from solver.sensors.errors import MetadataError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("import-sensor", help="vendor sensor metadata (Maxar XML, DIMAP of SPOT 1-7 and Pleiades) as a job "
                       "fragment: cameras, images with ephemeris and attitude, options")
    p.add_argument("metadata", type=Path, nargs="+", help="Maxar/DigitalGlobe support-data XML, SPOT 1-5 DIMAP v1 "
                   "METADATA.DIM or SPOT 6/7 / Pleiades DIMAP v2 DIM_*.XML (one per image)")
    p.add_argument("--image-id", action="append", default=[], metavar="ID",
                   help="image id, once per file in order (default: the file name without extension)")
    p.add_argument("-o", "--output", type=Path, help="JSON file to write (default: standard output)")
    p.add_argument("--check-rpc", action="store_true",
                   help="also compare the exact model with the vendor's RPC of each image (a DIMAP v2 product's "
                   "RPC_*.XML beside it), or else with the product's tie points or extent corners (standard error)")
    p.add_argument("--indent", type=int, default=2, help="JSON indentation (default 2)")
    p.set_defaults(func=run)


def _fail(message: str) -> int:
    print(f"pba import-sensor: {message}", file=sys.stderr)
    return 2


def run(args: argparse.Namespace) -> int:
    from solver.sensors.agreement import rpc_agreement
    from solver.sensors.dimap_spot5 import Spot5Product, tie_point_check
    from solver.sensors.dimap_v2 import DimapV2Product
    from solver.sensors.formats import read_product
    from solver.sensors.job_fragment import fragment

    if args.image_id and len(args.image_id) != len(args.metadata):
        return _fail(f"{len(args.image_id)} --image-id for {len(args.metadata)} files: give one per file, or none")
    ids = args.image_id or [p.stem for p in args.metadata]
    if len(set(ids)) != len(ids):
        return _fail(f"image ids must differ: {', '.join(ids)}")
    try:
        products = [read_product(p, str(p)) for p in args.metadata]
        doc = fragment(products, ids)
    except MetadataError as exc:
        return _fail(str(exc))
    for note in doc.pop("sensor_metadata"):
        d = note["difference_px"]
        print(f"{note['image']}: {note['satellite']} ({note['band']}), first line {note['first_line_utc']} "
              f"(times in s since {note['time_origin_utc']}); job form vs exact model {d['rms']:.3f} px RMS, "
              f"{d['max']:.3f} px max", file=sys.stderr)
    if args.check_rpc:
        for image_id, p in zip(ids, products):
            if isinstance(p, DimapV2Product):
                if not _check_dimap_v2(image_id, p):
                    return 2
                continue
            if isinstance(p, Spot5Product):
                c = tie_point_check(p)
                shown = ", ".join(f"{d:.2f}" for d in c["distances_m"])
                print(f"{image_id}: exact model vs the product's {c['points']} tie points within the look-angle table: "
                      f"{shown or 'none'} m", file=sys.stderr)
                continue
            if p.rpc is None:
                print(f"{image_id}: no RPB in {p.file}", file=sys.stderr)
                continue
            a = rpc_agreement(p.model, p.rpc)
            print(f"{image_id}: exact model vs vendor RPC over {a['points']} points: {a['rms_px']:.3f} px RMS, "
                  f"{a['max_px']:.3f} px max (line mean {a['line_mean_px']:+.3f}, column mean {a['column_mean_px']:+.3f})",
                  file=sys.stderr)
    text = json.dumps(doc, indent=args.indent) + "\n"
    if args.output:
        args.output.write_text(text)
        print(f"{args.output}: {len(ids)} image(s)", file=sys.stderr)
    else:
        sys.stdout.write(text)
    return 0


def _check_dimap_v2(image_id: str, p) -> bool:  # noqa: ANN001 (DimapV2Product, imported lazily)
    """The exact model of a DIMAP v2 product against its RPC (beside the metadata file) and each
    correction's size, else against its extent corners (standard error); False (a message
    printed) when the RPC file is bad."""
    from solver.importers.errors import SourceError
    from solver.importers.rpc import read_rpc
    from solver.sensors.agreement import correction_sizes, rpc_agreement
    from solver.sensors.dimap_v2 import extent_check

    if p.rpc_path is None:
        c = extent_check(p)
        where = f"at their common height {c['height_m']:.1f} m" if c["height_m"] is not None else "at their heights"
        shown = ", ".join(f"{d:.2f}" for d in c["distances_m"])
        missing = f"no {p.rpc_name} beside {p.file}; " if p.rpc_name else "no RPC component named; "
        print(f"{image_id}: {missing}exact model vs the product's {c['points']} extent corners {where}: {shown or 'none'} m",
              file=sys.stderr)
        return True
    try:
        rpc = read_rpc(p.rpc_path, str(p.rpc_path))
    except SourceError as exc:
        for problem in exc.source_problems:
            print(f"pba import-sensor: {problem}", file=sys.stderr)
        return False
    a = rpc_agreement(p.model, rpc)
    print(f"{image_id}: exact model vs vendor RPC ({p.rpc_path.name}) over {a['points']} points: {a['rms_px']:.3f} px RMS, "
          f"{a['max_px']:.3f} px max (line mean {a['line_mean_px']:+.3f}, column mean {a['column_mean_px']:+.3f})", file=sys.stderr)
    for name, size in correction_sizes(p.model.with_corrections(aberration=True, light_time=True, refraction=True), rpc).items():
        print(f"{image_id}: {name} (off by default) would move image positions by {size['shift_rms_px']:.2f} px RMS",
              file=sys.stderr)
    return True
