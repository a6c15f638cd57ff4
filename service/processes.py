"""The three OGC processes the server offers and their descriptions.

``bundle-adjustment`` adjusts one job (``solver.api.run``); ``model-comparison`` adjusts the
same observations with several platform models (``solver.api.compare``); ``preanalysis``
predicts the precision of a planned block before anything is measured
(``solver.api.preanalyse``). All take the job document as input ``job`` and return one output
``report`` (docs/report-contract.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any

from service.schemas import InputDescription, Link, OutputDescription, ProcessDescription
from solver.schema.job import Job

BUNDLE_ADJUSTMENT = "bundle-adjustment"
MODEL_COMPARISON = "model-comparison"
PREANALYSIS = "preanalysis"
VERSION = "1.0.0"


@dataclass(frozen=True)
class ProcessInfo:
    """Static facts about a process."""

    id: str
    title: str
    description: str


PROCESSES: dict[str, ProcessInfo] = {
    BUNDLE_ADJUSTMENT: ProcessInfo(
        BUNDLE_ADJUSTMENT,
        "Bundle adjustment of pushbroom images",
        "Estimates the platform-model parameters of every image (and the tie points) from "
        "image observations of control and tie points, and reports sigmas, correlations, "
        "residuals and check-point statistics.",
    ),
    MODEL_COMPARISON: ProcessInfo(
        MODEL_COMPARISON,
        "Platform model comparison",
        "Adjusts the same observations with each of several platform models and reports one "
        "adjustment per model plus a side-by-side table of sigma0, chi-square verdicts and "
        "check-point RMSE.",
    ),
    PREANALYSIS: ProcessInfo(
        PREANALYSIS,
        "Pre-analysis of a planned block",
        "Predicts the precision (sigmas and error ellipses) of the check, tie and control points "
        "of a planned block from the planned point coordinates and the images' approximate "
        "orientation, before anything is measured; image observations are not needed.",
    ),
}


@lru_cache(maxsize=1)
def job_schema() -> dict[str, Any]:
    """JSON schema of the job document (from the one pydantic model)."""
    return Job.model_json_schema()


def model_names() -> list[str]:
    """Names of the registered platform models."""
    from solver.platforms import model_names as names

    return list(names())


def describe(process_id: str, base_url: str) -> ProcessDescription:
    """The OGC process description of ``process_id`` (KeyError when unknown)."""
    info = PROCESSES[process_id]
    inputs = {
        "job": InputDescription(
            title="Job document",
            description="cameras, images with their platform models, ground points, image "
            "observations and options (schema_version 1.0); camera refs name cameras in "
            "/cameras",
            schema=job_schema(),
        )
    }
    if process_id == MODEL_COMPARISON:
        inputs["models"] = InputDescription(
            title="Platform models",
            description="models to compare (default: the job's options.models)",
            minOccurs=0,
            maxOccurs=1,
            schema={
                "type": "array",
                "minItems": 1,
                "items": {"type": "string", "enum": model_names()},
            },
        )
    outputs = {
        "report": OutputDescription(
            title={BUNDLE_ADJUSTMENT: "Adjustment report", PREANALYSIS: "Pre-analysis report"}.get(
                process_id, "Comparison report"
            ),
            description="see docs/report-contract.md",
            schema={"type": "object", "contentMediaType": "application/json"},
        )
    }
    href = f"{base_url}processes/{process_id}"
    return ProcessDescription(
        id=info.id,
        title=info.title,
        description=info.description,
        version=VERSION,
        jobControlOptions=["sync-execute", "async-execute", "dismiss"],
        outputTransmission=["value"],
        inputs=inputs,
        outputs=outputs,
        links=[
            Link(href=href, rel="self", type="application/json", title="process description"),
            Link(
                href=f"{href}/execution",
                rel="http://www.opengis.net/def/rel/ogc/1.0/execute",
                type="application/json",
                title="execute",
            ),
        ],
    )
