"""``pba import-rpc FILE [-o rpc.json] [--image-id ID --model RPC-DRIFT] [--pixel-convention gdal]``:
the RPC of a raster, ``NAME_RPC.TXT``, ``NAME.RPB`` or DIMAP RPC XML as the job's
``images[].rpc`` object (:mod:`solver.importers.rpc`). Exit status 0, or 2 with a message
naming the file when GDAL reads no RPC from it.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from solver.geometry.rpc import BIAS_MODELS, PIXEL_CONVENTIONS
from solver.importers.errors import SourceError
from solver.importers.rpc import image_entry, rpc_object


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "import-rpc",
        help="an RPC00B GDAL reads (IMAGE.tif, NAME_RPC.TXT, NAME.RPB, DIMAP RPC XML) as the job's images[].rpc object",
    )
    p.add_argument("source", type=Path, help="IMAGE.tif (tags or sidecar beside it), NAME_RPC.TXT, NAME.RPB or a DIMAP RPC_*.XML")
    p.add_argument("-o", "--output", type=Path, help="JSON file to write (default: standard output)")
    p.add_argument("--image-id", help="write a whole RPC image {id, rpc, model} with this id (camera omitted)")
    p.add_argument("--model", choices=tuple(BIAS_MODELS), default="RPC-DRIFT",
                   help="bias model of the image entry written with --image-id (default RPC-DRIFT)")
    p.add_argument("--pixel-convention", choices=PIXEL_CONVENTIONS, default="center",
                   help="center (default: ours and RPC00B's, the top-left pixel's centre at 0,0) or gdal "
                   "(GDAL's transformer, corner at 0,0: line_off and samp_off + 0.5)")
    p.add_argument("--indent", type=int, default=2, help="JSON indentation (default 2)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    try:
        if args.image_id:
            doc = image_entry(args.source, args.image_id, args.model, args.pixel_convention)
        else:
            doc = rpc_object(args.source, args.pixel_convention)
    except SourceError as exc:
        for p in exc.source_problems:
            print(f"pba import-rpc: {p}", file=sys.stderr)
        return 2
    text = json.dumps(doc, indent=args.indent) + "\n"
    if args.output:
        args.output.write_text(text)
        print(f"{args.output}: RPC of {args.source}", file=sys.stderr)
    else:
        sys.stdout.write(text)
    return 0
