"""Model comparison: the same observations adjusted with several platform models, side by side.

Reproduces the layout of seed 000 Tables 4-5 and 8-9 in one call (``pba compare``): for each
model the a-posteriori sigma0, the chi-square test, residual RMSE in x_s/y_s (mm), check-point
RMSE (E, N, planimetric) and the t-tests of the discrepancies. A model that cannot be solved
(for example rank-deficient with the given control) gets an ``error`` entry instead of a report.
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from solver.adjust import adjust_job
from solver.engine.validate import comparison_problems, handed
from solver.errors import JobError
from solver.platforms import get_model
from solver.schema.job import Job

__all__ = ["compare_models", "comparison_problems"]


def _row(model: str, report: dict[str, Any]) -> dict[str, Any]:
    a = report["adjustment"]
    chi = a.get("chi2") or {}
    cp = report.get("checkpoints") or {}
    rm = cp.get("rmse_m") or {}
    tt = cp.get("t_test") or {}
    xs = [im["residual_rmse"]["x_mm"] for im in report["images"] if im["residual_rmse"]["x_mm"] is not None]
    ys = [im["residual_rmse"]["y_mm"] for im in report["images"] if im["residual_rmse"]["y_mm"] is not None]
    return {
        "model": model,
        "sigma0": a.get("sigma0_aposteriori"),
        "dof": a.get("dof"),
        "chi2_statistic": chi.get("statistic"),
        "chi2_critical": chi.get("critical"),
        "chi2_passed": chi.get("passed"),
        "rmse_x_mm": float(np.sqrt(np.mean(np.square(xs)))) if xs else None,
        "rmse_y_mm": float(np.sqrt(np.mean(np.square(ys)))) if ys else None,
        "check_rmse_e_m": rm.get("e"),
        "check_rmse_n_m": rm.get("n"),
        "check_rmse_u_m": rm.get("u"),
        "check_rmse_planimetric_m": rm.get("planimetric"),
        "t_test_e_passed": (tt.get("e") or {}).get("passed"),
        "t_test_n_passed": (tt.get("n") or {}).get("passed"),
        "converged": a.get("converged"),
    }


def compare_models(
    job: Job,
    models: list[str],
    progress: Callable[..., None] | None = None,
    cancel: Callable[[], bool] | None = None,
    validated: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Adjust ``job`` once per model (every image switched to that model; an RPC bias model
    switches the RPC images, a rigorous model the images with a camera). ``validated``: the
    record of a validation already made (solver.api.validation_record), taken for every
    model's adjustment instead of checking the job again for each."""
    problems = comparison_problems(models, ("options", "models"))
    if problems:
        raise JobError(problems)
    plain = job.model_copy(update={"options": job.options.model_copy(update={"models": []})})
    subject = handed(plain, validated)  # the counts handed for the job serve every model's adjustment
    reports: dict[str, Any] = {}
    table = []
    n = len(models)
    for k, name in enumerate(models):
        # an RPC bias model replaces the models of the RPC images, a rigorous one those of the others
        rpc = not get_model(name).kind.has_camera  # an RPC bias model
        override = {im.id: name for im in job.images if (im.rpc is not None) == rpc}
        if not override:
            kind = "RPC" if rpc else "camera (rigorous)"
            table.append({"model": name, "error": f"the job has no {kind} image for model {name}"})
            reports[name] = {"error": {"message": table[-1]["error"]}}
            continue
        try:
            rep = adjust_job(subject, progress=progress, cancel=cancel, models=override, fraction_range=(k / n, (k + 1) / n))
        except JobError as exc:
            reports[name] = {"error": exc.to_dict() | {"message": str(exc)}}
            table.append({"model": name, "error": str(exc)})
            continue
        reports[name] = rep
        table.append(_row(name, rep))
    return {"kind": "comparison", "job_name": job.name, "models": list(models), "reports": reports, "table": table}


def _f(x: Any, spec: str) -> str:
    if x is None:
        return "-"
    if isinstance(x, bool):
        return "yes" if x else "NO"
    return format(x, spec)


def comparison_table_text(report: dict[str, Any]) -> str:
    """Plain-text side-by-side table of a comparison report."""
    head = (
        f"{'model':<8} {'sigma0':>7} {'chi2':>8} {'crit':>7} {'ok':>3} {'x_s mm':>8} {'y_s mm':>8} "
        f"{'E m':>7} {'N m':>7} {'plan m':>7} {'t(E)':>5} {'t(N)':>5}"
    )
    lines = [head, "-" * len(head)]
    for r in report["table"]:
        if "error" in r:
            lines.append(f"{r['model']:<8} error: {r['error'][:90]}")
            continue
        lines.append(
            f"{r['model']:<8} {_f(r['sigma0'], '7.3f')} {_f(r['chi2_statistic'], '8.2f')} {_f(r['chi2_critical'], '7.2f')} "
            f"{_f(r['chi2_passed'], '>3'):>3} {_f(r['rmse_x_mm'], '8.4f')} {_f(r['rmse_y_mm'], '8.4f')} "
            f"{_f(r['check_rmse_e_m'], '7.2f')} {_f(r['check_rmse_n_m'], '7.2f')} {_f(r['check_rmse_planimetric_m'], '7.2f')} "
            f"{_f(r['t_test_e_passed'], '>5'):>5} {_f(r['t_test_n_passed'], '>5'):>5}"
        )
    return "\n".join(lines)
