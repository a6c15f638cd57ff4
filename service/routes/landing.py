"""Landing page and conformance (OGC API - Common / Processes core)."""

from __future__ import annotations

from fastapi import APIRouter, Request

from service.deps import BaseUrl
from service.schemas import Conformance, LandingPage, Link

router = APIRouter(tags=["capabilities"])

OGC_REL = "http://www.opengis.net/def/rel/ogc/1.0/"
CONFORMANCE = [
    "http://www.opengis.net/spec/ogcapi-common-1/1.0/conf/core",
    "http://www.opengis.net/spec/ogcapi-processes-1/1.0/conf/core",
    "http://www.opengis.net/spec/ogcapi-processes-1/1.0/conf/ogc-process-description",
    "http://www.opengis.net/spec/ogcapi-processes-1/1.0/conf/json",
    "http://www.opengis.net/spec/ogcapi-processes-1/1.0/conf/job-list",
    "http://www.opengis.net/spec/ogcapi-processes-1/1.0/conf/dismiss",
]


@router.get("/", response_model=LandingPage, response_model_exclude_none=True)
def landing_page(request: Request, base: BaseUrl) -> LandingPage:
    """Landing page: what this server is and where its resources are."""
    links = [
        Link(href=base, rel="self", type="application/json", title="this document"),
        Link(
            href=f"{base}openapi.json",
            rel="service-desc",
            type="application/vnd.oai.openapi+json;version=3.1",
            title="API definition (OpenAPI)",
        ),
        Link(href=f"{base}docs", rel="service-doc", type="text/html", title="API documentation"),
        Link(
            href=f"{base}conformance",
            rel=OGC_REL + "conformance",
            type="application/json",
            title="conformance classes",
        ),
        Link(
            href=f"{base}processes",
            rel=OGC_REL + "processes",
            type="application/json",
            title="processes",
        ),
        Link(href=f"{base}jobs", rel=OGC_REL + "job-list", type="application/json", title="jobs"),
        Link(href=f"{base}cameras", rel="data", type="application/json", title="camera library"),
    ]
    if "ui" in getattr(request.app.state, "router_modules", ()):
        links.append(Link(href=f"{base}ui", rel="alternate", type="text/html", title="web page"))
    return LandingPage(
        title="Pushbroom orientation server",
        description="Bundle adjustment of pushbroom (linear-array) satellite images as OGC API - "
        "Processes: submit a job document, follow its progress, read the report.",
        links=links,
    )


@router.get("/conformance", response_model=Conformance)
def conformance() -> Conformance:
    """Conformance classes this server implements."""
    return Conformance(conformsTo=CONFORMANCE)
