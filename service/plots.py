"""Plots of an adjustment report (docs/report-contract.md): pure functions from the report dict to
a matplotlib ``Figure``, and :func:`render` to PNG or SVG bytes.

Everything drawn comes from the report; nothing here does adjustment mathematics, only display
arithmetic (a correlation matrix from a covariance matrix, a histogram, an arrow scale).
Units: ground discrepancies in metres in the local geodetic system (LGS: east, north, up at the
centroid of the control points), scene positions in kilometres of LGS, image positions and
residuals in pixels (line, column; line 0 at the top of the image).

Plot kinds (:data:`PLOT_KINDS`; adding one is a function plus an entry there):

* ``planimetric-discrepancies`` - check-point discrepancy vectors over the scene, with their
  predicted error ellipses at the same exaggeration, and the east/north discrepancies against
  a 1-GSD circle (seed 001 Figures 15, 18);
* ``height-discrepancies`` - up discrepancies over the scene and per point (seed 001 Figure 16);
  not for mono check points, which are projected at their known height;
* ``image-residuals`` - residual vectors over the image frame, per image;
* ``residual-histograms`` - standardized residuals (line, column) with the normal curve;
* ``correlations`` - the correlation matrices of each image's parameters and of each camera's
  interior orientation (from the covariances in the report) as heat maps;
* ``cost`` - the cost per iteration (``adjustment.cost_history``);
* ``error-ellipses`` - predicted horizontal error ellipses of check, tie and control points over
  the scene (issue 15); also the map of a pre-analysis report (``kind == "preanalysis"``);
* ``model-rmse`` - per-model check-point RMSE bars of a model comparison (seed 000 Figures 3, 4).

A plot that does not apply raises :class:`PlotNotApplicable`; an image or model that is not in
the report raises :class:`NoSuchSelection`. On a comparison report (``kind == "comparison"``) the
single-adjustment kinds draw one model's report (``model``; default the first that succeeded).

matplotlib is imported on first use, with its Agg and SVG canvases only (never pyplot), so
importing this module is cheap; :func:`plot_bytes` serialises drawing with a lock because
matplotlib does not promise thread safety.
"""

from __future__ import annotations

import io
import math
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

Report = dict[str, Any]

FORMATS: dict[str, str] = {"png": "image/png", "svg": "image/svg+xml"}
PNG_DPI = 110
MAX_IMAGE_PANELS = 6  # per-image kinds without image=ID draw at most this many images
MAX_VECTORS_PER_IMAGE = 3000  # residual arrows per image panel (every k-th above that)
MAX_CONTEXT_POINTS = 2000  # tie points drawn as context on scene plots

# colours: components and point roles, the same on every plot
C_E, C_N, C_U, C_PLAN = "#1f77b4", "#ff7f0e", "#2ca02c", "#9467bd"
C_CHECK, C_GCP, C_TIE = "#d62728", "#1f77b4", "#8c8c8c"
ROLE_COLOURS = {"gcp": C_GCP, "check": C_CHECK, "tie": C_TIE, "rejected": "#c20078"}


def _role(o: dict[str, Any]) -> str:
    """The observation's point role, or ``rejected`` for an image point removed by data
    snooping (``observations[].rejected``, docs/quality.md)."""
    return "rejected" if o.get("rejected") else str(o.get("role"))

_STYLE = {
    "font.size": 9,
    "axes.titlesize": 10,
    "axes.labelsize": 9,
    "legend.fontsize": 8,
    "xtick.labelsize": 8,
    "ytick.labelsize": 8,
    "figure.titlesize": 11,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "grid.linewidth": 0.6,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "svg.hashsalt": "pba-plots",
}

_LOCK = threading.Lock()


class PlotNotApplicable(ValueError):
    """The plot does not apply to this report (no check points, no covariance, ...)."""


class NoSuchSelection(LookupError):
    """The ``image`` or ``model`` asked for is not in the report."""


# -- report access ----------------------------------------------------------------------------
def adjustment_report(report: Report, model: str | None = None) -> Report:
    """The single adjustment to draw: ``report`` itself, or one model's report of a comparison
    (``model``, default the first model that succeeded). ``model`` is ignored otherwise."""
    if report.get("kind") != "comparison":
        return report
    reports = report.get("reports") or {}
    if model is None:
        for name in report.get("models") or list(reports):
            sub = reports.get(name)
            if isinstance(sub, dict) and "error" not in sub:
                return sub
        raise PlotNotApplicable("no model of this comparison produced a report")
    sub = reports.get(model)
    if not isinstance(sub, dict):
        raise NoSuchSelection(f"model {model!r} is not in this comparison")
    if "error" in sub:
        err = sub["error"]
        why = err.get("detail") or err.get("message") if isinstance(err, dict) else err
        raise PlotNotApplicable(f"model {model} failed: {why}")
    return sub


def _select_images(report: Report, image: str | None) -> list[dict[str, Any]]:
    images = [im for im in report.get("images") or [] if isinstance(im, dict)]
    if image is None:
        return images
    chosen = [im for im in images if im.get("id") == image]
    if not chosen:
        raise NoSuchSelection(f"image {image!r} is not in this report")
    return chosen


def _num(value: Any) -> float | None:
    """A finite float, or None (the report writes NaN as null)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value) if math.isfinite(value) else None


def _has_xy(values: Any) -> bool:
    """``values`` starts with two finite numbers (east, north)."""
    return (
        isinstance(values, (list, tuple))
        and len(values) >= 2
        and _num(values[0]) is not None
        and _num(values[1]) is not None
    )


def _checkpoint_points(report: Report) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    cps = report.get("checkpoints") or {}
    points = [
        p
        for p in cps.get("points") or []
        if isinstance(p, dict)
        and _num((p.get("discrepancy_m") or {}).get("e")) is not None
        and _num((p.get("discrepancy_m") or {}).get("n")) is not None
        and _has_xy(p.get("known_lgs_m"))
    ]
    if not points:
        raise PlotNotApplicable("the job has no check points with discrepancies")
    return cps, points


def _gsd_m(report: Report) -> float | None:
    """Ground sample distance for the 1-GSD references: the check points', else the images'."""
    gsd = _num((report.get("checkpoints") or {}).get("gsd_m"))
    if gsd:
        return gsd
    values = [_num(im.get("gsd_m")) for im in report.get("images") or []]
    values = [v for v in values if v]
    return float(np.mean(values)) if values else None


TITLE_SEPARATOR = "  |  "


def _job_name(report: Report) -> str:
    name = str(report.get("job_name") or "").strip()
    if len(name) > 70:
        name = name[:67] + "..."
    return f"{TITLE_SEPARATOR}{name}" if name else ""


def _fit_title(fig: Figure, title: str) -> str:
    """``title`` on two lines (before the job name) when one line would not fit the figure."""
    char_in = 0.55 * _STYLE["figure.titlesize"] / 72  # a rough average glyph width, inches
    if len(title) * char_in > fig.get_size_inches()[0] - 0.3:
        return title.replace(TITLE_SEPARATOR, "\n", 1)
    return title


def _suptitle(fig: Figure, title: str) -> None:
    fig.suptitle(_fit_title(fig, title))


def _observations(report: Report, image: str | None) -> list[dict[str, Any]]:
    return [
        o
        for o in report.get("observations") or []
        if isinstance(o, dict) and (image is None or o.get("image") == image)
    ]


# -- figure helpers ---------------------------------------------------------------------------
@contextmanager
def _style() -> Iterator[None]:
    import matplotlib

    with matplotlib.rc_context(_STYLE):
        yield


def _figure(width_in: float, height_in: float) -> Figure:
    from matplotlib.figure import Figure

    return Figure(figsize=(width_in, height_in), layout="constrained")


def _bands(fig: Figure, title: str, top_in: float = 0.4, bottom_in: float = 0.0) -> float:
    """Put ``title`` in a band of ``top_in`` inches at the top and keep a band of ``bottom_in``
    inches free at the bottom, both outside the constrained layout (which mis-places a
    suptitle over equal-aspect axes); returns the bottom band's height in figure units."""
    title = _fit_title(fig, title)
    top_in += 0.2 * title.count("\n")
    height_in = fig.get_size_inches()[1]
    top, bottom = top_in / height_in, bottom_in / height_in
    fig.get_layout_engine().set(rect=(0, bottom, 1, 1 - top - bottom))
    fig.text(
        0.5, 1 - top / 2, title, ha="center", va="center", fontsize=_STYLE["figure.titlesize"]
    ).set_in_layout(False)
    return bottom


def _nice(value: float) -> float:
    """A round number (1, 2 or 5 times a power of ten) close to ``value`` (> 0)."""
    exp = math.floor(math.log10(value))
    for m in (1.0, 2.0, 5.0, 10.0):
        if value <= m * 10**exp * 1.5:
            return m * 10**exp
    return 10.0 ** (exp + 1)


def _stride(n: int, limit: int) -> int:
    return max(1, math.ceil(n / limit))


def _scene_context(ax: Axes, report: Report) -> None:
    """Control points (triangles) and tie points (grey dots) in LGS kilometres, as context."""
    ties = [t["lgs_m"][:2] for t in report.get("tie_points") or [] if _has_xy(t.get("lgs_m"))]
    if ties:
        t = np.asarray(ties[:: _stride(len(ties), MAX_CONTEXT_POINTS)], dtype=float) / 1000.0
        ax.scatter(t[:, 0], t[:, 1], s=3, color=C_TIE, alpha=0.35, lw=0, label="tie point")
    gcps = [c["lgs_m"][:2] for c in report.get("control_points") or [] if _has_xy(c.get("lgs_m"))]
    if gcps:
        g = np.asarray(gcps, dtype=float) / 1000.0
        ax.scatter(g[:, 0], g[:, 1], s=22, marker="^", color=C_GCP, label="control point")


def _text_box(ax: Axes, text: str, loc: str = "upper left") -> None:
    x, ha = (0.02, "left") if "left" in loc else (0.98, "right")
    y, va = (0.98, "top") if "upper" in loc else (0.02, "bottom")
    ax.text(
        x,
        y,
        text,
        transform=ax.transAxes,
        ha=ha,
        va=va,
        fontsize=8,
        bbox={"boxstyle": "round,pad=0.35", "fc": "white", "ec": "0.8", "alpha": 0.9},
        zorder=10,
    )


def _fmt(value: Any, digits: int = 2, unit: str = "") -> str:
    v = _num(value)
    return "-" if v is None else f"{v:.{digits}f}{unit}"


# -- plots ------------------------------------------------------------------------------------
def planimetric_discrepancies(report: Report, image: str | None = None) -> Figure:
    """Check-point discrepancies (estimated - known, east/north): (a) as vectors at the points
    over the scene, exaggerated, with a 1-GSD scale arrow; (b) east against north with the
    1-GSD circle (the expected planimetric accuracy) and the mean."""
    cps, points = _checkpoint_points(report)
    gsd = _gsd_m(report)
    pos = np.array([p["known_lgs_m"][:2] for p in points], dtype=float) / 1000.0
    d = np.array([[p["discrepancy_m"]["e"], p["discrepancy_m"]["n"]] for p in points], float)
    ids = [str(p.get("id", "")) for p in points]
    length = np.hypot(d[:, 0], d[:, 1])

    fig = _figure(11.0, 5.2)
    ax1, ax2 = fig.subplots(1, 2, width_ratios=[1.3, 1.0])
    _scene_context(ax1, report)
    span = float(np.ptp(pos, axis=0).max()) if len(pos) > 1 else 1.0
    span = max(span, 1.0)
    ref_m = max(float(length.max()), gsd or 0.0, 1e-6)
    scale = 0.09 * span / ref_m  # km of map per metre of discrepancy
    q = ax1.quiver(
        pos[:, 0],
        pos[:, 1],
        d[:, 0] * scale,
        d[:, 1] * scale,
        angles="xy",
        scale_units="xy",
        scale=1.0,
        color=C_CHECK,
        width=0.004,
        zorder=4,
    )
    ax1.scatter(pos[:, 0], pos[:, 1], s=14, color=C_CHECK, zorder=5, label="check point")
    n_ell = _draw_ellipses(ax1, [p.get("error_ellipse") for p in points], pos, scale, C_CHECK)
    if n_ell:
        ax1.plot([], [], color=C_CHECK, lw=0.8, ls="-", label="predicted 1-sigma ellipse")
    key_m = gsd if gsd else _nice(ref_m)
    key_label = f"1 GSD = {gsd:.2f} m" if gsd else f"{key_m:g} m"
    ax1.quiverkey(q, 0.80, 1.03, key_m * scale, key_label, labelpos="E", coordinates="axes")
    ax1.set_aspect("equal", adjustable="datalim")
    ax1.set_xlabel("east (km, LGS)")
    ax1.set_ylabel("north (km, LGS)")
    ax1.set_title(f"(a) discrepancy vectors over the scene (x{scale * 1000:.0f})", loc="left")
    ax1.legend(loc="lower left", framealpha=0.9)

    from matplotlib.patches import Circle

    lim = 1.2 * max(float(length.max()), gsd or 0.0, 1e-3)
    if gsd:
        ax2.add_patch(Circle((0, 0), gsd, fill=False, ls="--", lw=1.2, color="0.2", label="1 GSD"))
    ax2.axhline(0, color="0.5", lw=0.8)
    ax2.axvline(0, color="0.5", lw=0.8)
    ax2.scatter(d[:, 0], d[:, 1], s=22, color=C_CHECK, zorder=4, label="check point")
    mean_e, mean_n = _num(cps.get("mean_m", {}).get("e")), _num(cps.get("mean_m", {}).get("n"))
    if mean_e is not None and mean_n is not None:
        ax2.plot(mean_e, mean_n, "kx", ms=9, mew=2, zorder=5, label="mean")
    if len(points) <= 40:
        for (x, y), label in zip(d, ids, strict=True):
            ax2.annotate(label, (x, y), xytext=(3, 3), textcoords="offset points", fontsize=7)
    ax2.set_xlim(-lim, lim)
    ax2.set_ylim(-lim, lim)
    ax2.set_aspect("equal")
    ax2.set_xlabel("east discrepancy (m)")
    ax2.set_ylabel("north discrepancy (m)")
    ax2.set_title("(b) east vs north discrepancies", loc="left")
    ax2.legend(loc="lower right", framealpha=0.9)
    rmse = cps.get("rmse_m") or {}
    lines = [
        f"RMSE E {_fmt(rmse.get('e'))} m, N {_fmt(rmse.get('n'))} m",
        f"planimetric {_fmt(rmse.get('planimetric'))} m",
    ]
    if gsd:
        inside = int(np.sum(length <= gsd))
        lines[-1] += f" ({_fmt((cps.get('rmse_gsd') or {}).get('planimetric'))} GSD)"
        lines.append(f"{inside} of {len(points)} within 1 GSD")
    _text_box(ax2, "\n".join(lines))
    method = cps.get("method") or "?"
    _suptitle(
        fig,
        f"Planimetric discrepancies at {len(points)} check points ({method}){_job_name(report)}",
    )
    return fig


def _ellipse_ok(e: Any) -> bool:
    return (
        isinstance(e, dict)
        and _num(e.get("semi_major_m")) is not None
        and _num(e.get("semi_minor_m")) is not None
        and _num(e.get("azimuth_deg")) is not None
    )


def _draw_ellipses(ax: Axes, ellipses: list[Any], centres_km: np.ndarray, scale: float, colour: str) -> int:
    """Standard error ellipses (``error_ellipse`` of the report: semi-axes in m, azimuth of the
    major axis clockwise from north) at ``centres_km``, exaggerated by ``scale`` (km per m)."""
    from matplotlib.patches import Ellipse

    n = 0
    for e, (x, y) in zip(ellipses, centres_km):
        if not _ellipse_ok(e):
            continue
        ax.add_patch(
            Ellipse(
                (x, y),
                2 * e["semi_major_m"] * scale,
                2 * e["semi_minor_m"] * scale,
                angle=90.0 - e["azimuth_deg"],  # matplotlib: counter-clockwise from east
                fill=False,
                lw=0.8,
                color=colour,
                zorder=3,
            )
        )
        n += 1
    return n


def _ellipse_points(report: Report) -> list[tuple[str, str, list[float], dict[str, Any]]]:
    """(id, role, LGS position, ellipse) of every point with a predicted error ellipse: check
    points, tie and control points of an adjustment, or the planned points of a pre-analysis."""
    out = []
    for p in (report.get("checkpoints") or {}).get("points") or []:
        xy = p.get("known_lgs_m") or p.get("planned_lgs_m")
        if _has_xy(xy) and _ellipse_ok(p.get("error_ellipse")):
            out.append((str(p.get("id", "")), "check", xy, p["error_ellipse"]))
    sections = [("tie", report.get("tie_points")), ("gcp", report.get("control_points"))]
    for role, items in sections:
        for p in items or []:
            if _has_xy(p.get("lgs_m")) and _ellipse_ok(p.get("error_ellipse")):
                out.append((str(p.get("id", "")), role, p["lgs_m"], p["error_ellipse"]))
    for p in report.get("points") or []:  # pre-analysis
        if _has_xy(p.get("planned_lgs_m")) and _ellipse_ok(p.get("error_ellipse")):
            out.append((str(p.get("id", "")), str(p.get("role")), p["planned_lgs_m"], p["error_ellipse"]))
    if not out:
        raise PlotNotApplicable("no predicted error ellipses (no covariance)")
    return out


def error_ellipses(report: Report, image: str | None = None) -> Figure:
    """Predicted horizontal standard error ellipses over the scene (check points red, tie grey,
    control blue), all exaggerated by one factor with a scale key: of an adjustment, or of a
    pre-analysis (the map of a planned control layout before anything is measured)."""
    pts = _ellipse_points(report)
    pos = np.array([p[2][:2] for p in pts], dtype=float) / 1000.0
    major = max(float(p[3]["semi_major_m"]) for p in pts)
    span = max(float(np.ptp(pos, axis=0).max()) if len(pos) > 1 else 1.0, 1.0)
    scale = 0.04 * span / max(major, 1e-9)
    fig = _figure(8.5, 7.0)
    ax = fig.subplots(1, 1)
    for role, label in (("tie", "tie point"), ("gcp", "control point"), ("check", "check point")):
        sel = [k for k, p in enumerate(pts) if p[1] == role]
        if not sel:
            continue
        colour = ROLE_COLOURS.get(role, C_TIE)
        _draw_ellipses(ax, [pts[k][3] for k in sel], pos[sel], scale, colour)
        marker = "^" if role == "gcp" else "o"
        ax.scatter(pos[sel, 0], pos[sel, 1], s=10 if role != "tie" else 4, marker=marker, color=colour, label=label, zorder=4)
    key = _nice(major)
    x0, y0 = pos[:, 0].min(), pos[:, 1].min() - 0.08 * span
    ax.plot([x0, x0 + key * scale], [y0, y0], color="k", lw=2)
    ax.annotate(f"{key:g} m (semi-axis x{scale * 1000:.0f})", (x0, y0), xytext=(0, 4), textcoords="offset points", fontsize=8)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("east (km, LGS)")
    ax.set_ylabel("north (km, LGS)")
    ax.legend(loc="upper right", framealpha=0.9)
    pr = (report.get("checkpoints") or {}).get("predicted_rmse_m") or {}
    if pr:
        _text_box(ax, f"predicted check RMSE E {_fmt(pr.get('e'))} m, N {_fmt(pr.get('n'))} m, U {_fmt(pr.get('u'))} m")
    what = "Pre-analysis" if report.get("kind") == "preanalysis" else "Predicted precision"
    _suptitle(fig, f"{what}: horizontal error ellipses (1 sigma){_job_name(report)}")
    return fig


def height_discrepancies(report: Report, image: str | None = None) -> Figure:
    """Up discrepancies of the check points: (a) over the scene, coloured; (b) per point with
    the +-1 GSD band and the mean. Mono check points have none (projected at known height)."""
    cps = report.get("checkpoints") or {}
    points = [
        p
        for p in cps.get("points") or []
        if isinstance(p, dict)
        and _num((p.get("discrepancy_m") or {}).get("u")) is not None
        and _has_xy(p.get("known_lgs_m"))
    ]
    if not points:
        if cps.get("method") == "mono":
            raise PlotNotApplicable(
                "mono check points are projected at their known height: no height discrepancies"
            )
        raise PlotNotApplicable("the job has no check points with height discrepancies")
    points = sorted(points, key=lambda p: str(p.get("id", "")))
    gsd = _gsd_m(report)
    pos = np.array([p["known_lgs_m"][:2] for p in points], dtype=float) / 1000.0
    du = np.array([p["discrepancy_m"]["u"] for p in points], dtype=float)
    ids = [str(p.get("id", "")) for p in points]
    vmax = max(float(np.abs(du).max()), 1e-3)

    fig = _figure(11.0, 4.8)
    ax1, ax2 = fig.subplots(1, 2, width_ratios=[1.0, 1.2])
    _scene_context(ax1, report)
    sc = ax1.scatter(
        pos[:, 0],
        pos[:, 1],
        c=du,
        cmap="RdBu_r",
        vmin=-vmax,
        vmax=vmax,
        s=30 + 90 * np.abs(du) / vmax,
        edgecolors="0.2",
        linewidths=0.6,
        zorder=4,
    )
    fig.colorbar(sc, ax=ax1, label="up discrepancy (m)", shrink=0.85)
    ax1.set_aspect("equal", adjustable="datalim")
    ax1.set_xlabel("east (km, LGS)")
    ax1.set_ylabel("north (km, LGS)")
    ax1.set_title("(a) over the scene", loc="left")
    if report.get("control_points") or report.get("tie_points"):
        ax1.legend(loc="lower left", framealpha=0.9)

    x = np.arange(len(points))
    ax2.bar(x, du, color=np.where(du >= 0, C_CHECK, C_GCP), width=0.7)
    if gsd:
        for sign in (1, -1):
            ax2.axhline(
                sign * gsd, ls="--", color="0.3", lw=1, label="\u00b11 GSD" if sign > 0 else None
            )
    mean_u = _num((cps.get("mean_m") or {}).get("u"))
    if mean_u is not None:
        ax2.axhline(mean_u, ls=":", color="k", lw=1.2, label=f"mean {mean_u:.2f} m")
    ax2.axhline(0, color="0.5", lw=0.8)
    ax2.set_xticks(x)
    ax2.set_xticklabels(ids if len(ids) <= 50 else [""] * len(ids), rotation=90, fontsize=7)
    ax2.set_ylabel("up discrepancy (m)")
    ax2.set_title("(b) per check point", loc="left")
    ax2.legend(loc="upper right", framealpha=0.9)
    rmse_u = (cps.get("rmse_m") or {}).get("u")
    std_u = (cps.get("std_m") or {}).get("u")
    _text_box(ax2, f"RMSE U {_fmt(rmse_u)} m\nstd {_fmt(std_u)} m", loc="upper left")
    method = cps.get("method") or "?"
    _suptitle(
        fig, f"Height discrepancies at {len(points)} check points ({method}){_job_name(report)}"
    )
    return fig


def _panel_grid(fig: Figure, n: int, ncols_max: int = 3) -> list[Axes]:
    ncols = min(ncols_max, n)
    nrows = math.ceil(n / ncols)
    axes = fig.subplots(nrows, ncols, squeeze=False).ravel().tolist()
    for ax in axes[n:]:
        ax.set_visible(False)
    return axes[:n]


def image_residuals(report: Report, image: str | None = None) -> Figure:
    """Image residual vectors (observed - adjusted, pixels) at the observations over each image
    frame, exaggerated by a common factor, with a scale arrow; one panel per image."""
    obs_by_image: dict[str, list[dict[str, Any]]] = {}
    for o in _observations(report, image):
        if any(
            _num(o.get(k)) is None
            for k in ("line", "column", "residual_line_px", "residual_column_px")
        ):
            continue
        obs_by_image.setdefault(str(o.get("image")), []).append(o)
    images = [im for im in _select_images(report, image) if str(im.get("id")) in obs_by_image]
    if not images:
        raise PlotNotApplicable("the report has no image residuals")
    shown = images[:MAX_IMAGE_PANELS]
    all_obs = [o for im in shown for o in obs_by_image[str(im["id"])] if not o.get("rejected")]
    all_obs = all_obs or [o for im in shown for o in obs_by_image[str(im["id"])]]
    lengths = np.hypot(
        [o["residual_line_px"] for o in all_obs], [o["residual_column_px"] for o in all_obs]
    )
    ref_px = max(float(np.percentile(lengths, 98)), 1e-6)
    frame = max(max(_num(im.get("lines")) or 0, _num(im.get("columns")) or 0) for im in shown)
    if frame <= 0:
        frame = float(max(max(o["line"], o["column"]) for o in all_obs))
    # the longest arrows (98th percentile) reach a tenth of the frame, or about the mean
    # spacing of the observations when they are dense
    densest = max(len(obs_by_image[str(im["id"])]) for im in shown)
    spacing = frame / math.sqrt(max(densest, 1))
    scale = min(0.1 * frame, 1.2 * spacing) / ref_px  # frame pixels per pixel of residual
    key_px = _nice(ref_px)

    ncols = min(3, len(shown))
    nrows = math.ceil(len(shown) / ncols)
    fig = _figure(4.3 * ncols + 0.4, 4.5 * nrows + 0.7)
    axes = _panel_grid(fig, len(shown))
    handles: dict[str, Any] = {}
    for ax, im in zip(axes, shown, strict=True):
        obs = obs_by_image[str(im["id"])]
        n_all = len(obs)
        step = _stride(n_all, MAX_VECTORS_PER_IMAGE)
        obs = obs[::step]
        lines = _num(im.get("lines")) or max(o["line"] for o in obs)
        cols = _num(im.get("columns")) or max(o["column"] for o in obs)
        from matplotlib.patches import Rectangle

        ax.add_patch(Rectangle((0, 0), cols, lines, fill=False, ec="0.3", lw=1))
        roles = sorted({_role(o) for o in obs}, key=lambda r: (r != "tie", r == "rejected", r))
        q = None
        for role in roles:
            sel = [o for o in obs if _role(o) == role]
            c = np.array([o["column"] for o in sel], float)
            ln = np.array([o["line"] for o in sel], float)
            rc = np.array([o["residual_column_px"] for o in sel], float)
            rl = np.array([o["residual_line_px"] for o in sel], float)
            colour = ROLE_COLOURS.get(role, "k")
            if role == "rejected":  # removed by data snooping: residual when it was rejected
                ax.scatter(c, ln, s=30, color=colour, marker="x", lw=1.2, zorder=3)
            else:
                ax.scatter(c, ln, s=4, color=colour, lw=0)
            q = ax.quiver(
                c,
                ln,
                rc * scale,
                rl * scale,
                angles="xy",
                scale_units="xy",
                scale=1.0,
                color=colour,
                width=0.004 if len(sel) < 300 else 0.0025,
                alpha=0.9 if role != "tie" else 0.7,
            )
            handles.setdefault(role, q)
        ax.set_xlim(-0.04 * cols, 1.04 * cols)
        ax.set_ylim(1.04 * lines, -0.04 * lines)  # line 0 at the top
        ax.set_aspect("equal")
        ax.set_xlabel("column (px)")
        ax.set_ylabel("line (px)")
        rmse = im.get("residual_rmse") or {}
        title = (
            f"{im['id']} ({im.get('model', '?')})\nRMSE line {_fmt(rmse.get('line_px'))} px, "
            f"column {_fmt(rmse.get('column_px'))} px"
        )
        if step > 1:
            title += f"\nevery {step}th of {n_all} observations"
        ax.set_title(title, fontsize=9)
    from matplotlib.lines import Line2D

    legend = [
        Line2D([], [], color=ROLE_COLOURS.get(r, "k"), lw=2, label=r) for r in sorted(handles)
    ]
    extra = (
        f" (first {len(shown)} of {len(images)} images; image=ID for another)"
        if len(images) > len(shown)
        else ""
    )
    band = _bands(
        fig,
        f"Image residual vectors (x{scale:.0f}){extra}{_job_name(report)}",
        bottom_in=0.4,
    )
    leg = fig.legend(
        handles=legend, loc="center", bbox_to_anchor=(0.62, band / 2), ncols=len(legend)
    )
    leg.set_in_layout(False)
    last = next(iter(handles.values()))
    key = last.axes.quiverkey(
        last,
        0.6 / fig.get_size_inches()[0],  # the arrow's centre, 0.6 inch from the left edge
        band / 2,
        key_px * scale,
        f"residual {key_px:g} px",
        labelpos="E",
        coordinates="figure",
        color="k",
    )
    key.set_in_layout(False)
    return fig


def _standardized(o: dict[str, Any], axis: str) -> float | None:
    value = _num(o.get(f"standardized_{axis}"))
    if value is not None:
        return value
    r, s = _num(o.get(f"residual_{axis}_px")), _num(o.get("sigma_px"))
    return r / s if r is not None and s else None


def residual_histograms(report: Report, image: str | None = None) -> Figure:
    """Histograms of the standardized residuals in line and column with the standard normal
    curve N(0, 1) (expected) and the normal curve of the sample's mean and deviation."""
    if image is not None:
        _select_images(report, image)
    obs = [o for o in _observations(report, image) if not o.get("rejected")]  # the final adjustment's
    series = {
        axis: np.array([v for o in obs if (v := _standardized(o, axis)) is not None], float)
        for axis in ("line", "column")
    }
    if not any(len(v) for v in series.values()):
        raise PlotNotApplicable("the report has no image residuals")
    fig = _figure(10.0, 4.2)
    axes = fig.subplots(1, 2, sharey=True)
    for ax, (axis, v), colour in zip(axes, series.items(), (C_E, C_N), strict=True):
        ax.set_title(f"standardized residuals, {axis}", loc="left")
        ax.set_xlabel("standardized residual")
        if not len(v):
            ax.text(0.5, 0.5, "no residuals", ha="center", transform=ax.transAxes)
            continue
        lim = float(min(8.0, max(4.0, math.ceil(np.abs(v).max()))))
        nbins = int(np.clip(math.sqrt(len(v)) * 1.5, 10, 60))
        clipped = np.clip(v, -lim, lim)
        ax.hist(
            clipped,
            bins=np.linspace(-lim, lim, nbins + 1),
            density=True,
            color=colour,
            alpha=0.7,
            edgecolor="white",
            label=f"{len(v)} residuals",
        )
        x = np.linspace(-lim, lim, 400)
        ax.plot(x, np.exp(-0.5 * x**2) / math.sqrt(2 * math.pi), "k-", lw=1.5, label="N(0, 1)")
        mean, std = float(v.mean()), float(v.std(ddof=1)) if len(v) > 1 else 0.0
        if std > 0:
            pdf = np.exp(-0.5 * ((x - mean) / std) ** 2) / (std * math.sqrt(2 * math.pi))
            ax.plot(x, pdf, "k--", lw=1, label=f"N({mean:.2f}, {std:.2f}\u00b2)")
        outside = int(np.sum(np.abs(v) > lim))
        text = f"mean {mean:.3f}\nstd {std:.3f}\nmax |r| {np.abs(v).max():.2f}"
        if outside:
            text += f"\n{outside} beyond \u00b1{lim:g} (in the edge bins)"
        _text_box(ax, text, loc="upper left")
        ax.legend(loc="upper right")
    axes[0].set_ylabel("density")
    where = image if image is not None else "all images"
    _suptitle(fig, f"Residual histograms ({where}){_job_name(report)}")
    return fig


def _correlation_matrix(cov: dict[str, Any]) -> tuple[list[str], np.ndarray] | None:
    names = [str(n) for n in cov.get("names") or []]
    matrix = cov.get("matrix") or []
    if not names or len(matrix) != len(names):
        return None
    c = np.array(
        [[np.nan if _num(x) is None else float(x) for x in row] for row in matrix], dtype=float
    )
    if c.shape != (len(names), len(names)):
        return None
    diag = np.diag(c)
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.sqrt(np.where(diag > 0, diag, np.nan))
        rho = np.clip(c / np.outer(s, s), -1.0, 1.0)
    return names, rho


def _correlation_panels(
    report: Report, image: str | None
) -> list[tuple[str, list[str], np.ndarray]]:
    """(title, names, correlation matrix) of each selected image's exterior-orientation
    covariance, then of the interior-orientation covariance of their cameras."""
    panels = []
    images = _select_images(report, image)
    for im in images:
        cov = im.get("covariance")
        found = _correlation_matrix(cov) if isinstance(cov, dict) else None
        if found is not None:
            panels.append((f"{im['id']} ({im.get('model', '?')})", *found))
    wanted = {str(im.get("camera")) for im in images} if image is not None else None
    for cam in report.get("cameras") or []:
        if not isinstance(cam, dict) or (wanted is not None and str(cam.get("id")) not in wanted):
            continue
        cov = cam.get("iop_covariance")
        found = _correlation_matrix(cov) if isinstance(cov, dict) else None
        if found is not None:
            panels.append((f"camera {cam.get('id')} (interior orientation)", *found))
    return panels


def correlations(report: Report, image: str | None = None) -> Figure:
    """The parameter correlation matrices, from the covariances in the report, as heat maps:
    each image's platform parameters, then each camera's interior orientation (self-calibration);
    cells at or above the report's correlation threshold are outlined."""
    mats = _correlation_panels(report, image)
    if not mats:
        raise PlotNotApplicable(
            "the report has no parameter covariance (options.covariance false, or not computable)"
        )
    threshold = _num((report.get("correlations") or {}).get("threshold")) or 0.75
    shown = mats[:MAX_IMAGE_PANELS]
    ncols = min(3, len(shown))
    nrows = math.ceil(len(shown) / ncols)
    size = max(4.2, 0.28 * max(len(m[1]) for m in shown) + 1.6)
    fig = _figure(size * ncols + 1.0, size * nrows + 0.6)
    axes = _panel_grid(fig, len(shown))
    from matplotlib.patches import Rectangle

    artist = None
    for ax, (title, names, rho) in zip(axes, shown, strict=True):
        n = len(names)
        artist = ax.imshow(rho, cmap="RdBu_r", vmin=-1, vmax=1, interpolation="nearest")
        ax.grid(False)
        ax.set_xticks(range(n))
        ax.set_yticks(range(n))
        ax.set_xticklabels(names, rotation=90, fontsize=7)
        ax.set_yticklabels(names, fontsize=7)
        flagged = 0
        for i in range(n):
            for j in range(n):
                r = rho[i, j]
                if not np.isfinite(r):
                    continue
                if i != j and abs(r) >= threshold:
                    flagged += 1
                    ax.add_patch(Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, ec="k", lw=1.3))
                if n <= 16:
                    ax.text(
                        j,
                        i,
                        f"{r:.2f}".replace("0.", ".").replace("1.00", "1"),
                        ha="center",
                        va="center",
                        fontsize=6 if n <= 12 else 5,
                        color="white" if abs(r) > 0.6 else "black",
                    )
        ax.set_title(
            f"{title}\n{flagged // 2} pair{'' if flagged == 2 else 's'} with |\u03c1| \u2265 "
            f"{threshold:g}",
            fontsize=9,
        )
    fig.colorbar(artist, ax=axes, shrink=0.8, label="correlation coefficient")
    extra = f" (first {len(shown)} of {len(mats)} images)" if len(mats) > len(shown) else ""
    # title and colour bar outside the constrained layout, which mis-sizes equal-aspect axes
    _bands(fig, f"Parameter correlations{extra}{_job_name(report)}", bottom_in=0.1)
    return fig


def cost(report: Report, image: str | None = None) -> Figure:
    """The cost (weighted sum of squared residuals as the solver reports it) per iteration."""
    adj = report.get("adjustment") or {}
    pts = [
        (h.get("iteration"), _num(h.get("cost")))
        for h in adj.get("cost_history") or []
        if isinstance(h, dict)
    ]
    pts = [(int(i), c) for i, c in pts if isinstance(i, int) and c is not None and c > 0]
    if not pts:
        raise PlotNotApplicable("the report has no cost history")
    it, c = zip(*pts, strict=True)
    fig = _figure(7.5, 4.2)
    ax = fig.subplots()
    ax.semilogy(it, c, "o-", color=C_E, lw=1.5, ms=5)
    from matplotlib.ticker import MaxNLocator

    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("iteration")
    ax.set_ylabel("cost")
    ax.annotate(
        f"{c[-1]:.4g}",
        (it[-1], c[-1]),
        xytext=(-6, 8),
        textcoords="offset points",
        ha="right",
        fontsize=8,
    )
    sigma0 = _num(adj.get("sigma0_aposteriori"))
    lines = [
        f"termination: {adj.get('termination', '?')}",
        f"iterations: {adj.get('iterations', len(pts))}",
    ]
    if sigma0 is not None:
        lines.append(f"sigma0 = {sigma0:.4f}")
    _text_box(ax, "\n".join(lines), loc="upper right")
    ax.set_title("Cost per iteration" + _job_name(report), loc="left")
    return fig


RMSE_COMPONENTS = (
    ("E", "check_rmse_e_m", C_E),
    ("N", "check_rmse_n_m", C_N),
    ("U", "check_rmse_u_m", C_U),
    ("planimetric", "check_rmse_planimetric_m", C_PLAN),
)


def model_rmse(report: Report, image: str | None = None) -> Figure:
    """Check-point RMSE (east, north, up when known, planimetric) per platform model of a model
    comparison, with the 1-GSD line (as seed 000 Figures 3 and 4)."""
    if report.get("kind") != "comparison":
        raise PlotNotApplicable("not a model comparison: per-model RMSE needs kind 'comparison'")
    rows = {r.get("model"): r for r in report.get("table") or [] if isinstance(r, dict)}
    reports = report.get("reports") or {}
    models = [str(m) for m in report.get("models") or list(rows)]
    comps = [
        (label, key, colour)
        for label, key, colour in RMSE_COMPONENTS
        if any(_num((rows.get(m) or {}).get(key)) is not None for m in models)
    ]
    if not models or not comps:
        raise PlotNotApplicable("the comparison has no check-point RMSE (no check points)")
    gsd = next(
        (
            g
            for m in models
            if isinstance(reports.get(m), dict)
            and "error" not in reports[m]
            and (g := _gsd_m(reports[m]))
        ),
        None,
    )
    fig = _figure(max(7.5, 1.1 * len(models) + 3.0), 4.6)
    ax = fig.subplots()
    x = np.arange(len(models))
    width = 0.8 / len(comps)
    top = 0.0
    for k, (label, key, colour) in enumerate(comps):
        values = [_num((rows.get(m) or {}).get(key)) for m in models]
        heights = [v if v is not None else 0.0 for v in values]
        top = max(top, *heights)
        bars = ax.bar(
            x + (k - (len(comps) - 1) / 2) * width, heights, width, label=label, color=colour
        )
        if len(models) <= 10:
            for bar, v in zip(bars, values, strict=True):
                if v is not None:
                    ax.annotate(
                        f"{v:.2f}",
                        (bar.get_x() + bar.get_width() / 2, v),
                        xytext=(0, 2),
                        textcoords="offset points",
                        ha="center",
                        fontsize=6.5,
                    )
    for i, m in enumerate(models):
        sub = reports.get(m)
        if m not in rows or (isinstance(sub, dict) and "error" in sub):
            ax.text(i, 0.02 * max(top, 1.0), "failed", ha="center", va="bottom", color=C_CHECK)
    if gsd:
        ax.axhline(gsd, ls="--", color="0.2", lw=1.2, label=f"1 GSD = {gsd:.2f} m")
    ax.set_xticks(x)
    ax.set_xticklabels(models)
    ax.set_xlabel("platform model")
    ax.set_ylabel("check-point RMSE (m)")
    ax.set_ylim(0, 1.15 * max(top, gsd or 0.0, 1e-3))
    ax.legend(loc="upper left", ncols=len(comps) + 1, framealpha=0.9)
    ax.set_title("Check-point RMSE per platform model" + _job_name(report), loc="left")
    return fig


# -- registry ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class PlotKind:
    """One kind of plot: its name in URLs, a title, whether it takes ``image``, and whether it
    draws a whole comparison (``comparison``) or one adjustment (``adjustment``)."""

    name: str
    title: str
    description: str
    draw: Callable[[Report, str | None], Figure]
    per_image: bool = False
    scope: str = "adjustment"


PLOT_KINDS: dict[str, PlotKind] = {
    k.name: k
    for k in (
        PlotKind(
            "planimetric-discrepancies",
            "Planimetric discrepancies",
            "check-point discrepancy vectors over the scene and against the 1-GSD circle",
            planimetric_discrepancies,
        ),
        PlotKind(
            "height-discrepancies",
            "Height discrepancies",
            "check-point up discrepancies over the scene and per point (not for mono check "
            "points)",
            height_discrepancies,
        ),
        PlotKind(
            "image-residuals",
            "Image residual vectors",
            "residual vectors over the image frame, per image (image=ID for one)",
            image_residuals,
            per_image=True,
        ),
        PlotKind(
            "residual-histograms",
            "Residual histograms",
            "standardized residuals in line and column with the normal curve (image=ID for one)",
            residual_histograms,
            per_image=True,
        ),
        PlotKind(
            "correlations",
            "Parameter correlations",
            "correlation matrices of each image's parameters (and of the cameras' interior "
            "orientation) as heat maps (image=ID for one)",
            correlations,
            per_image=True,
        ),
        PlotKind("cost", "Cost per iteration", "the solver's cost per iteration", cost),
        PlotKind(
            "error-ellipses",
            "Predicted error ellipses",
            "horizontal 1-sigma error ellipses of check, tie and control points over the scene "
            "(an adjustment's predicted precision, or a pre-analysis of a planned layout)",
            error_ellipses,
        ),
        PlotKind(
            "model-rmse",
            "Check-point RMSE per model",
            "per-model check-point RMSE bars of a model comparison",
            model_rmse,
            scope="comparison",
        ),
    )
}


def plot(report: Report, kind: str, image: str | None = None, model: str | None = None) -> Figure:
    """The figure of ``kind`` for ``report`` (KeyError for an unknown kind; PlotNotApplicable,
    NoSuchSelection as documented above)."""
    spec = PLOT_KINDS[kind]
    with _style():
        if spec.scope == "comparison":
            return spec.draw(report, None)
        return spec.draw(adjustment_report(report, model), image if spec.per_image else None)


def render(fig: Figure, fmt: str) -> bytes:
    """``fig`` as PNG or SVG bytes."""
    if fmt not in FORMATS:
        raise ValueError(f"unknown format {fmt!r}")
    buf = io.BytesIO()
    with _style():
        if fmt == "png":
            fig.savefig(buf, format="png", dpi=PNG_DPI, facecolor="white")
        else:
            fig.savefig(buf, format="svg", metadata={"Date": None}, facecolor="white")
    return buf.getvalue()


def plot_bytes(
    report: Report, kind: str, fmt: str, image: str | None = None, model: str | None = None
) -> bytes:
    """:func:`plot` then :func:`render`, one figure at a time."""
    with _LOCK:
        return render(plot(report, kind, image, model), fmt)


def applicable(report: Report, model: str | None = None) -> list[str]:
    """The kinds that apply to ``report`` (each one's checks, without drawing)."""
    out = []
    for name, spec in PLOT_KINDS.items():
        try:
            _check(report, spec, model)
        except (PlotNotApplicable, NoSuchSelection):
            continue
        out.append(name)
    return out


def _check(report: Report, spec: PlotKind, model: str | None) -> None:
    """Raise PlotNotApplicable unless ``spec`` applies to ``report`` (cheap, no drawing)."""
    if spec.scope == "comparison":
        if report.get("kind") != "comparison":
            raise PlotNotApplicable("not a model comparison")
        return
    sub = adjustment_report(report, model)
    name = spec.name
    if name == "planimetric-discrepancies":
        _checkpoint_points(sub)
    elif name == "height-discrepancies":
        pts = (sub.get("checkpoints") or {}).get("points") or []
        if not any(_num((p.get("discrepancy_m") or {}).get("u")) is not None for p in pts):
            raise PlotNotApplicable("no height discrepancies")
    elif name in ("image-residuals", "residual-histograms"):
        if not any(_num(o.get("residual_line_px")) is not None for o in _observations(sub, None)):
            raise PlotNotApplicable("no residuals")
    elif name == "correlations":
        if not _correlation_panels(sub, None):
            raise PlotNotApplicable("no covariance")
    elif name == "cost":
        if not (sub.get("adjustment") or {}).get("cost_history"):
            raise PlotNotApplicable("no cost history")
    elif name == "error-ellipses":
        _ellipse_points(sub)
