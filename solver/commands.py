"""``pba run``, ``pba validate``, ``pba models`` and ``pba compare``: the solver's own commands."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any, TextIO

from solver.errors import Cancelled, JobError
from solver.report.json_text import report_json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="adjust a job document and write its report")
    p.add_argument("job", type=Path, help="job document (JSON)")
    p.add_argument("-o", "--output", type=Path, help="report file (JSON); default: stdout summary only")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("validate", help="check a job document without solving it")
    p.add_argument("job", type=Path, help="job document (JSON)")
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser("models", help="list the platform models and their parameters")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_models)

    p = sub.add_parser("export-camera", help="camera definition with the IOP a self-calibration estimated")
    p.add_argument("job", type=Path, help="the self-calibration job document")
    p.add_argument("report", type=Path, help="its report (pba run -o)")
    p.add_argument("--camera", required=True, help="camera id")
    p.add_argument("-o", "--output", type=Path, help="camera definition (JSON); default stdout")
    p.set_defaults(func=cmd_export_camera)

    p = sub.add_parser(
        "warmup", help="compile the numba kernels into their disk cache (first job fast)"
    )
    p.add_argument(
        "--jobs",
        type=_positive_int,
        metavar="N",
        help="processes that compile at once: 2 or more warm the Python evaluation path in a second process beside the compiled one (default: 2 on a machine of two or more cores, else 1)",
    )
    p.set_defaults(func=cmd_warmup)

    p = sub.add_parser(
        "preanalysis", help="predicted precision of a planned block (planned points, approximate orientation)"
    )
    p.add_argument("job", type=Path, help="job document with planned point coordinates (observations ignored)")
    p.add_argument("-o", "--output", type=Path, help="pre-analysis report (JSON)")
    p.set_defaults(func=cmd_preanalysis)

    p = sub.add_parser("compare", help="adjust one job with several platform models side by side")
    p.add_argument("job", type=Path, help="job document (JSON)")
    p.add_argument("--models", required=True, help="comma-separated, e.g. K1,K2,J2-1,J2-2,ON1,ON2,P1,P2")
    p.add_argument("-o", "--output", type=Path, help="comparison report (JSON)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_compare)


class ProgressBar:
    """A one-line text progress bar on stderr (fraction 0..1 with a message)."""

    def __init__(self, stream: TextIO = sys.stderr, width: int = 30, enabled: bool = True):
        self.stream = stream
        self.width = width
        self.enabled = enabled and stream.isatty() or enabled == "force"
        self.t0 = time.perf_counter()

    def __call__(self, fraction: float, message: str, info: dict[str, Any] | None = None) -> None:
        if info and info.get("kernels_compiling"):  # a notice of its own line, bar or not
            self.stream.write(("\n" if self.enabled else "") + message + "\n")
            self.stream.flush()
            return
        if not self.enabled:
            return
        n = int(round(fraction * self.width))
        bar = "#" * n + "-" * (self.width - n)
        self.stream.write(f"\r[{bar}] {fraction * 100:5.1f}% {time.perf_counter() - self.t0:6.1f}s {message[:50]:<50}")
        self.stream.flush()
        if fraction >= 1.0:
            self.stream.write("\n")


def _load(path: Path) -> Any:
    from pydantic import ValidationError

    from solver.schema.job import load_job

    try:
        return load_job(path.read_text())
    except ValidationError as exc:
        print(f"{path}: invalid job document:", file=sys.stderr)
        for err in exc.errors():
            loc = "/".join(str(x) for x in err["loc"])
            print(f"  {loc}: {err['msg']}", file=sys.stderr)
        raise SystemExit(2) from None
    except OSError as exc:
        print(f"cannot read {path}: {exc}", file=sys.stderr)
        raise SystemExit(2) from None


def _print_problems(exc: JobError) -> None:
    print("the job cannot be solved:", file=sys.stderr)
    for p in exc.problems:
        loc = "/".join(str(x) for x in p.location)
        print(f"  [{p.code}] {loc}: {p.message}", file=sys.stderr)


def _fmt(x: Any, spec: str = ".4g") -> str:
    return "-" if x is None else format(x, spec)


def summary_text(report: dict[str, Any]) -> str:
    """Human summary of an adjustment report (the table printed by ``pba run``)."""
    a = report["adjustment"]
    lines = [
        f"job: {report.get('job_name')}",
        f"observations {a['n_observations']}  unknowns {a['n_unknowns']}  dof {a['dof']}  "
        f"iterations {a['iterations']}  {a['termination']}  solve {a['solve_time_s']:.3f} s",
    ]
    chi = a.get("chi2")
    s0 = a.get("sigma0_aposteriori")
    lines.append(
        f"sigma0 a posteriori {_fmt(s0)}"
        + (
            f"   chi2 {chi['statistic']:.3f} vs [{chi['critical_lower']:.2f}, {chi['critical']:.2f}] "
            f"({'passed' if chi['passed'] else 'REJECTED'})"
            if chi
            else ""
        )
    )
    for img in report["images"]:
        r = img["residual_rmse"]
        lines.append(
            f"\nimage {img['id']} ({img['model']}, {img['frame']})  residual RMSE line {_fmt(r['line_px'], '.3f')} px, "
            f"column {_fmt(r['column_px'], '.3f')} px"
        )
        lines.append(f"  {'parameter':<10} {'value':>20} {'sigma':>12}  unit")
        for p in img["parameters"]:
            flag = "" if p["estimated"] else "  (held)"
            lines.append(f"  {p['name']:<10} {p['value']:>20.10g} {_fmt(p['sigma'], '12.4g'):>12}  {p['unit']}{flag}")
    for cam in report.get("cameras") or []:
        lines.append(f"\ncamera {cam['id']} interior orientation (master chip {cam.get('master_chip')})")
        for p in cam["parameters"]:
            flag = "" if p["estimated"] else "  (given)"
            sig = "" if p["significant"] is None else ("" if p["significant"] else "  |value| < sigma")
            lines.append(f"  {p['name']:<10} {p['value']:>20.10g} {_fmt(p['sigma'], '12.4g'):>12}  {p['unit']}{flag}{sig}")
    pa = report.get("parameter_analysis")
    if pa:
        lines.append(f"\nsignificance analysis: {len(pa['steps'])} adjustments, dropped {', '.join(pa['dropped']) or 'nothing'}")
    cp = report.get("checkpoints") or {}
    if cp.get("n"):
        rm = cp["rmse_m"]
        lines.append(
            f"\ncheck points ({cp['n']}, {cp['method']}): RMSE E {_fmt(rm['e'], '.3f')} m  N {_fmt(rm['n'], '.3f')} m  "
            f"U {_fmt(rm['u'], '.3f')} m  planimetric {_fmt(rm['planimetric'], '.3f')} m"
            + (f"  ({rm['planimetric'] / cp['gsd_m']:.2f} GSD)" if cp.get("gsd_m") and rm.get("planimetric") else "")
        )
        pr = cp.get("predicted_rmse_m")
        if pr:
            ratio = cp.get("rmse_ratio") or {}
            lines.append(
                f"  predicted RMSE E {_fmt(pr['e'], '.3f')} m  N {_fmt(pr['n'], '.3f')} m  U {_fmt(pr['u'], '.3f')} m  "
                f"(empirical / predicted: E {_fmt(ratio.get('e'), '.2f')}  N {_fmt(ratio.get('n'), '.2f')}  "
                f"U {_fmt(ratio.get('u'), '.2f')}); {cp.get('n_discrepancy_test_failed', 0)} point(s) fail the discrepancy test"
            )
        for axis in ("e", "n", "u"):
            t = cp["t_test"].get(axis)
            if t:
                lines.append(
                    f"  t-test {axis}: t={t['statistic']:.3f} critical {t['critical']:.3f} "
                    f"({'no bias' if t['passed'] else 'BIASED'})"
                )
    loo = (report.get("quality") or {}).get("leave_one_out")
    if loo and loo.get("n_determined"):
        rm, pr = loo["rmse_m"], loo["predicted_rmse_m"]
        lines.append(
            f"\nleave-one-out ({loo['n_determined']} of {loo['n']} control points): cross-validation RMSE "
            f"E {_fmt(rm['e'], '.3f')} m  N {_fmt(rm['n'], '.3f')} m  U {_fmt(rm['u'], '.3f')} m "
            f"(predicted E {_fmt(pr['e'], '.3f')}  N {_fmt(pr['n'], '.3f')}  U {_fmt(pr['u'], '.3f')}); "
            f"{loo['n_discrepancy_test_failed']} fail the discrepancy test"
        )
    pairs = (report.get("quality") or {}).get("tie_pairs")
    if pairs:
        lines.append("\ntie points per image pair (found / kept / removed by data snooping):")
        lines += [f"  {p['images'][0]}-{p['images'][1]}: {p['found']} / {p['kept']} / {p['removed']}" for p in pairs]
    ln = report.get("lines") or {}
    if ln.get("items"):
        roles = [it["role"] for it in ln["items"]]
        model = ln["model"] + (f", correction {ln['correction']}" if ln.get("correction") else "")
        rm = ln["rmse_px"]
        lines.append(
            f"\nlines ({roles.count('control')} control, {roles.count('check')} check; {model}): image distance "
            f"RMSE control {_fmt(rm['control'], '.3f')} px, check {_fmt(rm['check'], '.3f')} px"
        )
    for w in report.get("warnings", []):
        lines.append(f"warning: {w}")
    return "\n".join(lines)


def cmd_run(args: argparse.Namespace) -> int:
    from solver import api

    job = _load(args.job)
    bar = ProgressBar(enabled=not args.quiet)
    try:
        report = api.run(job, progress=bar)
    except JobError as exc:
        _print_problems(exc)
        return 2
    except Cancelled as exc:
        print(f"cancelled: {exc}", file=sys.stderr)
        return 3
    if args.output:
        args.output.write_text(report_json(report, indent=1))
    if report.get("kind") == "comparison":
        from solver.compare import comparison_table_text

        print(comparison_table_text(report))
    else:
        print(summary_text(report))
    return 0


def preanalysis_text(report: dict[str, Any]) -> str:
    """Human summary of a pre-analysis report (``pba preanalysis``)."""
    a = report["adjustment"]
    lines = [
        f"pre-analysis of {report.get('job_name')}: {a['n_planned_image_points']} planned image points, "
        f"{a['n_unknowns']} unknowns, dof {a['dof']} (sigma0 a priori {a['sigma0_apriori']:g})"
    ]
    cp = report["checkpoints"]
    pr = cp.get("predicted_rmse_m")
    if pr:
        lines.append(
            f"check points ({cp['n']}): predicted RMSE E {_fmt(pr['e'], '.3f')} m  N {_fmt(pr['n'], '.3f')} m  "
            f"U {_fmt(pr['u'], '.3f')} m  3D {_fmt(pr['3d'], '.3f')} m"
        )
        lines.append(f"  {'point':<12} {'sigma E':>9} {'sigma N':>9} {'sigma U':>9}  images")
        for p in cp["points"]:
            s = p["sigma_m"] or {}
            lines.append(
                f"  {p['id']:<12} {_fmt(s.get('e'), '9.3f')} {_fmt(s.get('n'), '9.3f')} {_fmt(s.get('u'), '9.3f')}  {len(p['images'])}"
            )
    for w in report["quality"]["warnings"][:10]:
        lines.append(f"warning: {w['message']}")
    return "\n".join(lines)


def cmd_preanalysis(args: argparse.Namespace) -> int:
    from solver import api

    job = _load(args.job)
    try:
        report = api.preanalyse(job)
    except JobError as exc:
        _print_problems(exc)
        return 2
    if args.output:
        args.output.write_text(report_json(report, indent=1))
    print(preanalysis_text(report))
    return 0


def cmd_validate(args: argparse.Namespace) -> int:
    from solver import api

    job = _load(args.job)
    result = api.validate(job)
    if result["valid"]:
        print(
            f"valid: {result['n_observations']} observations, {result['n_unknowns']} unknowns, "
            f"{result['dof']} degrees of freedom"
        )
        return 0
    for p in result["problems"]:
        print(f"[{p['code']}] {'/'.join(str(x) for x in p['location'])}: {p['message']}")
    return 2


def cmd_models(args: argparse.Namespace) -> int:
    from solver.platforms import all_models

    models = [m.describe() for m in all_models()]
    if args.json:
        print(json.dumps(models, indent=1))
        return 0
    for m in models:
        print(f"{m['name']:<8} {m['title']}")
        print(f"         frame {m['frame']}; time {m['time_variable']}")
        print("         parameters: " + ", ".join(f"{p['name']} [{p['unit']}]" for p in m["parameters"]))
        if m.get("pass_parameters"):
            print("         per pass (shared by its images, at the reference epoch): " + ", ".join(f"{p['name']} [{p['unit']}]" for p in m["pass_parameters"]))
        if m["held"]:
            print("         held: " + ", ".join(m["held"]) + "  options: " + "; ".join(f"{k}: {v}" for k, v in m["options"].items()))
        print(f"         {m['reference']}")
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    from solver import api
    from solver.compare import comparison_table_text

    job = _load(args.job)
    models = [m.strip() for m in args.models.split(",") if m.strip()]
    bar = ProgressBar(enabled=not args.quiet)
    try:
        report = api.compare(job, models, progress=bar)
    except JobError as exc:
        _print_problems(exc)
        return 2
    if args.output:
        args.output.write_text(report_json(report, indent=1))
    print(comparison_table_text(report))
    return 0


def cmd_export_camera(args: argparse.Namespace) -> int:
    """Write the job's camera with the estimated IOP and their covariance, ready to reuse in
    another job (``iop_use``: "fixed", or "weighted" with the same parameters estimated)."""
    from solver.observations.interior import NoEstimatedCamera, camera_from_report

    job = json.loads(args.job.read_text())
    report = json.loads(args.report.read_text())
    try:
        definition = camera_from_report(job, report, args.camera)
    except NoEstimatedCamera as exc:
        print(f"{args.report}: {exc}", file=sys.stderr)
        return 2
    text = json.dumps(definition, indent=1)
    if args.output:
        args.output.write_text(text)
    else:
        print(text)
    return 0


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text}")
    return value


def cmd_warmup(args: argparse.Namespace) -> int:
    """``pba warmup``: adjust the tiny warm-up jobs, printing each one's time (``--jobs``: in
    how many processes, :func:`solver.warmup.compile_kernels`)."""
    from solver.kernels.cache import cache_dir
    from solver.warmup import WarmupError, compile_kernels, default_processes

    processes = args.jobs if args.jobs is not None else default_processes()
    try:
        total = compile_kernels(say=print, processes=processes)
    except WarmupError as exc:
        print(f"pba warmup: {exc}", file=sys.stderr)
        return 1
    print(f"kernels compiled or loaded from the cache in {total:.1f} s ({cache_dir()})")
    return 0
