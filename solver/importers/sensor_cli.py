"""``pba import-sensor METADATA... [--image-id ID]... [-o fragment.json] [--check-rpc] [--strict]``: vendors'
sensor metadata (Maxar/DigitalGlobe support-data XML, DIMAP v1 of SPOT 1-5, DIMAP v2 of SPOT 6/7
and Pleiades, INPE product XML of CBERS-4/4A and Amazonia-1) as a fragment of the job document:
``cameras`` (one per image), ``images`` (ephemeris, attitude samples, first-line time, a default
model) and ``options`` (ephemeris and attitude weights from the file's covariances), as JSON.

On standard error, per image: what was read and how far the job form is from the vendor's
exact model (px); with ``--check-rpc`` also the exact model against the vendor's RPC of the
same image (RMS and maximum px over image positions x heights; a DIMAP v2 product's RPC_*.XML is
looked for beside its DIM_*.XML), or, without an RPC, with the product's own tie points or extent
corners (metres; for CBERS, its corners in px). The reader's screening (a conversion it made: ``note:``;
samples it did not use: ``warning:``) is printed and kept in the job (``images[].sensor``).
Then the self-check (:mod:`solver.sensors.self_check`): one line when every comparison is within
its limit, a loud ``WARNING`` per comparison beyond it (``--strict``: exit 2 and write nothing).
Exit 0, or 2 with a message naming the file and the element at fault (docs/sensor-metadata.md).

``pba check-sensor METADATA... [--image-id ID]... [--rpc FILE]... [--json] [--strict]``: the
self-check's table of every product: its corners and centres, its RPC (or the one given), and
the job form, against the exact model and the job form, in pixels and metres with the limits
(the role of ASP's ``cam_test``).

``pba simulate-measurements METADATA... [--image-id ID]... -o DIR``: a stand-in for a lab's own
survey and image measurements when only the metadata is at hand: control, check and tie points
simulated on the metadata's exact models, each image's direct georeferencing off by a few metres
(:mod:`solver.sensors.simulated`), written as the files ``pba job`` reads (``control.csv``,
``checks.csv``: WGS 84 longitude, latitude, ellipsoidal height; ``ID.csv``: image measurements)
and the truth (``truth.json``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from solver.gis.results_cli import announcing
from solver.sensors.errors import MetadataError


def _metadata_args(p: argparse.ArgumentParser) -> None:
    """The metadata files and their image ids (``import-sensor``, ``simulate-measurements``)."""
    p.add_argument("metadata", type=Path, nargs="+", help="Maxar/DigitalGlobe support-data XML, SPOT 1-5 DIMAP v1 "
                   "METADATA.DIM, SPOT 6/7 / Pleiades DIMAP v2 DIM_*.XML or INPE CBERS/Amazonia product XML, "
                   "FILE#left or FILE#right for one camera of a two-camera record, FILE#raw (FILE#right,raw) for "
                   "measurements in the raw image an INPE record describes (its raster is a map grid); one per image")
    p.add_argument("--image-id", action="append", default=[], metavar="ID",
                   help="image id, once per file in order (default: the file name without extension)")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("import-sensor", help="vendor sensor metadata (Maxar XML, DIMAP of SPOT 1-7 and Pleiades, INPE "
                       "CBERS XML) as a job fragment: cameras, images with ephemeris and attitude, options")
    _metadata_args(p)
    p.add_argument("-o", "--output", type=Path, help="JSON file to write (default: standard output)")
    p.add_argument("--check-rpc", action="store_true",
                   help="also compare the exact model with the vendor's RPC of each image (a DIMAP v2 product's "
                   "RPC_*.XML beside it), or else with the product's tie points or extent corners (standard error)")
    p.add_argument("--indent", type=int, default=2, help="JSON indentation (default 2)")
    p.add_argument("--strict", action="store_true",
                   help="exit 2 (writing nothing) when the self-check finds a reference beyond its limit (pba check-sensor)")
    p.set_defaults(func=announcing(run))

    p = sub.add_parser("check-sensor", help="check vendor sensor metadata against everything it states: corners, scene "
                       "centres, the vendor's RPC, and the job form (the orientation a job composed from it starts from)")
    _metadata_args(p)
    p.add_argument("--rpc", action="append", default=[], type=Path, metavar="FILE",
                   help="an RPC of the image to compare with (NAME_RPC.TXT, .RPB, a raster with RPC tags; read by GDAL), "
                   "once per metadata file in order; default: the product's own RPC where it has one")
    p.add_argument("--json", action="store_true", help="the rows as JSON on standard output instead of the table")
    p.add_argument("--strict", action="store_true", help="exit 2 when a reference is beyond its limit")
    p.set_defaults(func=announcing(run_check))

    p = sub.add_parser("simulate-measurements", help="survey and image measurements simulated on vendor metadata's exact "
                       "models (a stand-in for your own): control.csv, checks.csv, ID.csv, truth.json")
    _metadata_args(p)
    p.add_argument("--gcps", type=int, default=4, help="control points (default 4)")
    p.add_argument("--checks", type=int, default=12, help="check points (default 12)")
    p.add_argument("--ties", type=int, default=20, help="tie points (default 20)")
    p.add_argument("--shift-sigma-m", type=float, default=3.0,
                   help="sigma of each image's ground shift, east and north, m: how far the metadata's direct "
                   "georeferencing misses (default 3)")
    p.add_argument("--noise-px", type=float, default=0.3, help="image measurement sigma, px (default 0.3)")
    p.add_argument("--survey-sigma-m", type=float, default=0.1, help="survey sigma of control and check points, m (default 0.1)")
    p.add_argument("--seed", type=int, default=1, help="random seed (same seed, same files)")
    p.add_argument("-o", "--output", type=Path, required=True, help="directory to write the files into")
    p.set_defaults(func=run_simulate)


def _ids(args: argparse.Namespace) -> list[str] | str:
    """The image ids of ``args.metadata``, or the message saying why they are wrong."""
    if args.image_id and len(args.image_id) != len(args.metadata):
        return f"{len(args.image_id)} --image-id for {len(args.metadata)} files: give one per file, or none"
    ids = args.image_id or [p.stem for p in args.metadata]
    if len(set(ids)) != len(ids):
        return f"image ids must differ: {', '.join(ids)}"
    return ids


def _fail(message: str) -> int:
    print(f"pba import-sensor: {message}", file=sys.stderr)
    return 2


def run(args: argparse.Namespace) -> int:
    from solver.sensors.agreement import rpc_agreement
    from solver.sensors.dimap_spot5 import Spot5Product, tie_point_check
    from solver.sensors.dimap_v2 import DimapV2Product
    from solver.sensors.formats import read_product
    from solver.sensors.inpe_cbers import CbersProduct, corner_check
    from solver.sensors.job_fragment import fragment

    ids = _ids(args)
    if isinstance(ids, str):
        return _fail(ids)
    try:
        products = [read_product(p, str(p)) for p in args.metadata]
        doc = fragment(products, ids)
    except MetadataError as exc:
        return _fail(str(exc))
    beyond = 0
    for note, product in zip(doc.pop("sensor_metadata"), products):
        d = note["difference_px"]
        print(f"{note['image']}: {note['satellite']} ({note['band']}), first line {note['first_line_utc']} "
              f"(times in s since {note['time_origin_utc']}); job form vs exact model {d['rms']:.3f} px RMS, "
              f"{d['max']:.3f} px max", file=sys.stderr)
        for w in note.get("notes", []):
            print(f"{note['image']}: note: {w}", file=sys.stderr)
        for w in note.get("warnings", []):
            print(f"{note['image']}: warning: {w}", file=sys.stderr)
        beyond += _self_check_summary(note["image"], product)
    if beyond and args.strict:
        return _fail(f"{beyond} self-check reference(s) beyond their limits (--strict): nothing written")
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
            if isinstance(p, CbersProduct):
                c = corner_check(p)
                held = ", ".join(f"{h['corner']} {h['px']:.2f}" for h in c["held_out"])
                print(f"{image_id}: model fitted to the corners {', '.join(c['corners'])}: {c['fit_rms_px']:.2f} px RMS, "
                      f"{c['fit_max_px']:.2f} px max" + (f"; each corner from the other three: {held} px" if held else ""),
                      file=sys.stderr)
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


def _self_check_summary(image_id: str, product) -> int:  # noqa: ANN001 (a reader's product, imported lazily)
    """Run the self-check of a product (:mod:`solver.sensors.self_check`) and print one line
    when every reference is within its limit, a loud one per reference beyond it; how many were."""
    from solver.sensors.self_check import self_check

    check = self_check(product)
    bad = check.failures()
    if not bad:
        worst = max(check.rows, key=lambda r: r.max_px / r.limit_px, default=None)
        said = f" (closest to its limit: {worst.reference}, {worst.model}, {worst.max_px:.3f} of {worst.limit_px:g} px)" if worst else ""
        print(f"{image_id}: self-check: {len(check.rows)} comparisons within their limits{said}", file=sys.stderr)
    for r in bad:
        print(f"{image_id}: WARNING: self-check: {r.reference} vs the {r.model} model: {r.max_px:.3f} px at worst "
              f"({r.rms_px:.3f} px RMS over {r.points}), beyond {r.limit_px:g} px: pba check-sensor shows every comparison",
              file=sys.stderr)
    for n in check.notes:
        if n.startswith("no job form"):
            print(f"{image_id}: WARNING: self-check: {n}", file=sys.stderr)
    return len(bad) + sum(1 for n in check.notes if n.startswith("no job form"))


def run_check(args: argparse.Namespace) -> int:
    """``pba check-sensor``: the self-check's table of every product (exit 2 with ``--strict``
    when a reference is beyond its limit)."""
    from solver.importers.errors import SourceError
    from solver.importers.rpc import read_rpc
    from solver.sensors.formats import read_product
    from solver.sensors.self_check import format_table, self_check

    def fail(message: str) -> int:
        print(f"pba check-sensor: {message}", file=sys.stderr)
        return 2

    ids = _ids(args)
    if isinstance(ids, str):
        return fail(ids)
    if args.rpc and len(args.rpc) != len(args.metadata):
        return fail(f"{len(args.rpc)} --rpc for {len(args.metadata)} files: give one per file, or none")
    try:
        products = [read_product(p, str(p)) for p in args.metadata]
    except MetadataError as exc:
        return fail(str(exc))
    rpcs = []
    for path in args.rpc:
        try:
            rpcs.append(read_rpc(path, str(path)))
        except SourceError as exc:
            return fail("; ".join(str(p) for p in exc.source_problems))
    checks = [self_check(p, rpcs[k] if rpcs else None, args.rpc[k].name if rpcs else "") for k, p in enumerate(products)]
    if args.json:
        sys.stdout.write(json.dumps([{"image": i, "file": c.file, "satellite": c.satellite, "passed": c.passed,
                                      "rows": [r.as_dict() for r in c.rows], "notes": c.notes}
                                     for i, c in zip(ids, checks)], indent=1) + "\n")
    else:
        for image_id, c in zip(ids, checks):
            print("\n".join(format_table(c, image_id)))
    beyond = sum(len(c.failures()) for c in checks)
    if beyond:
        print(f"pba check-sensor: {beyond} comparison(s) beyond their limits", file=sys.stderr)
    return 2 if beyond and args.strict else 0


def _check_dimap_v2(image_id: str, p) -> bool:  # noqa: ANN001 (DimapV2Product, imported lazily)
    """The exact model of a DIMAP v2 product against its RPC (beside the metadata file) and each
    correction's size, else against its extent corners (standard error); False (a message
    printed) when the RPC file is bad."""
    from solver.importers.errors import SourceError
    from solver.importers.rpc import read_rpc
    from solver.sensors.agreement import correction_sizes, rpc_agreement
    from solver.sensors.dimap_v2 import extent_check

    if p.rpc_path is None and p.rpc is None:
        c = extent_check(p)
        where = f"at their common height {c['height_m']:.1f} m" if c["height_m"] is not None else "at their heights"
        shown = ", ".join(f"{d:.2f}" for d in c["distances_m"])
        missing = f"no {p.rpc_name} beside {p.file}; " if p.rpc_name else "no RPC component named; "
        print(f"{image_id}: {missing}exact model vs the product's {c['points']} extent corners {where}: {shown or 'none'} m",
              file=sys.stderr)
        return True
    if p.rpc is not None:
        rpc, rpc_name = p.rpc, "the global RFM of the metadata file"
    else:
        try:
            rpc = read_rpc(p.rpc_path, str(p.rpc_path))
        except SourceError as exc:
            for problem in exc.source_problems:
                print(f"pba import-sensor: {problem}", file=sys.stderr)
            return False
        rpc_name = p.rpc_path.name
    a = rpc_agreement(p.model, rpc)
    print(f"{image_id}: exact model vs vendor RPC ({rpc_name}) over {a['points']} points: {a['rms_px']:.3f} px RMS, "
          f"{a['max_px']:.3f} px max (line mean {a['line_mean_px']:+.3f}, column mean {a['column_mean_px']:+.3f})", file=sys.stderr)
    for name, size in correction_sizes(p.model.with_corrections(aberration=True, light_time=True, refraction=True), rpc).items():
        print(f"{image_id}: {name} (off by default) would move image positions by {size['shift_rms_px']:.2f} px RMS",
              file=sys.stderr)
    return True


def run_simulate(args: argparse.Namespace) -> int:
    from solver.importers.measurements_csv import write_measurements
    from solver.importers.points_csv import write_points
    from solver.sensors.formats import read_product
    from solver.sensors.simulated import height_range, simulate_measurements

    def fail(message: str) -> int:
        print(f"pba simulate-measurements: {message}", file=sys.stderr)
        return 2

    ids = _ids(args)
    if isinstance(ids, str):
        return fail(ids)
    try:
        products = [read_product(p, str(p)) for p in args.metadata]
    except MetadataError as exc:
        return fail(str(exc))
    try:
        sim = simulate_measurements([p.model for p in products], ids, height_range(getattr(products[0], "rpc", None)),
                                    args.gcps, args.checks, args.ties, args.shift_sigma_m, args.noise_px,
                                    args.survey_sigma_m, args.seed)
    except ValueError as exc:
        return fail(str(exc))
    out = args.output
    out.mkdir(parents=True, exist_ok=True)
    for name, role in (("control.csv", "gcp"), ("checks.csv", "check")):
        (out / name).write_text(write_points([p for p in sim.points if p["role"] == role], "EPSG:4326", with_role=False))
    for image_id in ids:
        (out / f"{image_id}.csv").write_text(write_measurements([o for o in sim.observations if o["image"] == image_id], with_image=False))
    (out / "truth.json").write_text(json.dumps(sim.truth, indent=1) + "\n")
    shifts = ", ".join(f"{i} {e:+.2f} E {n:+.2f} N" for i, (e, n) in sim.truth["image_shifts_en_m"].items())
    print(f"{out}: control.csv ({args.gcps} points), checks.csv ({args.checks}), {', '.join(f'{i}.csv' for i in ids)} "
          f"({args.gcps + args.checks + args.ties} points each), truth.json; direct georeferencing off by (m) {shifts}",
          file=sys.stderr)
    return 0
