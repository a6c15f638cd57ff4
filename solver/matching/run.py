"""Matching as one call for a worker (the server's ``match`` process): rasters named by the
job's image ids, progress and cancel hooks, the result as a document, every bad input a
:class:`solver.errors.JobError`.

The result (``kind`` ``"tie-points"``): ``observations``, the measurements as the job's
``observations`` entries (``image, point, line, column, sigma_px``: pixels, our convention,
so the server's observations table is the tie CSV ``pba job`` reads), and ``summary``, the
summary of ``pba match --summary`` (docs/matching.md).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from solver.errors import Cancelled, JobError, Problem
from solver.matching.features import MatchSettings

RESULT_KIND = "tie-points"


def _image_index(job: dict[str, Any], image_id: str) -> tuple[str | int, ...]:
    """The location of image ``image_id`` in the job (``("images", k)``), or ``()``."""
    for k, im in enumerate(job.get("images") or []):
        if isinstance(im, dict) and im.get("id") == image_id:
            return ("images", k)
    return ()


def run_matching(
    job: dict[str, Any],
    rasters: list[tuple[str, Path, str]],
    heights_m: tuple[float, float] | None = None,
    settings: MatchSettings | None = None,
    progress: Callable[..., None] | None = None,
    cancel: Callable[[], bool] | None = None,
) -> dict[str, Any]:
    """Tie points of ``rasters`` ((job image id, raster path, the name messages give the
    raster), at least two) guided by the job's initial orientation; ``heights_m`` the
    terrain's ellipsoidal range (default: the job's or the RPCs'). Raises :class:`JobError`
    (unreadable, truncated or absurd raster, a size the job disagrees with, no overlap,
    nothing matched; located at the job's image) and :class:`Cancelled`."""
    from solver.gis.model import ModelMismatch
    from solver.matching.orientation import OrientationError, images_from_job
    from solver.matching.pipeline import MatchError, failure_advice, match_images
    from solver.matching.raster import RasterError

    def hook(fraction: float, message: str) -> None:
        if cancel is not None and cancel():
            raise Cancelled("matching cancelled")
        if progress is not None:
            progress(fraction, message)

    def located(message: str) -> JobError:
        where: tuple[str | int, ...] = ()
        for image_id, path, name in rasters:
            if str(path) in message:
                message, where = message.replace(str(path), name), _image_index(job, image_id)
        return JobError(Problem("unusable_raster", message, where))

    images = []
    try:
        images, default_heights = images_from_job(job, None, [f"{image_id}={path}" for image_id, path, _ in rasters])
        result = match_images(images, heights_m or default_heights, settings or MatchSettings(), hook)
    except (RasterError, OrientationError, ModelMismatch) as exc:
        raise located(str(exc)) from None
    except MatchError as exc:
        raise JobError(Problem("no_tie_points", str(exc), detail={"summary": exc.summary} if exc.summary else {})) from None
    finally:
        for im in images:
            im.raster.close()
    if not result.measurements:
        raise JobError(Problem("no_tie_points", "no tie point survived the checks: " + failure_advice(result.summary),
                               detail={"summary": result.summary}))
    return {"kind": RESULT_KIND, "observations": result.measurements, "summary": result.summary}
