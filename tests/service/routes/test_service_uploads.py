"""Hostile uploads to ``POST /jobs/compose`` (in process): every one ends in a located 4xx
problem document, decided before the work it would cost (names, nesting, field sizes, XML GDAL
half-reads, rows, columns and repeated references), and a property-based fuzz of the multipart
endpoint (hostile names, sizes, encodings, nested JSON, XML bombs, binary) never gets a 5xx."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Iterator

import pytest
from fastapi.testclient import TestClient
from test_service_api import assert_problem, make_client
from test_service_compose import example_files, example_spec, upload

# An XML GDAL half-reads as a DIMAP RPC (validity fields without coefficients): before, rasterio
# raised KeyError 'HEIGHT_OFF' and the server answered 500.
HALF_RPC_XML = (
    b"<?xml version='1.0'?><Dimap_Document><Rational_Function_Model><Global_RFM><RFM_Validity>"
    b"<LONG_SCALE>1</LONG_SCALE><LAT_SCALE>1</LAT_SCALE></RFM_Validity></Global_RFM>"
    b"</Rational_Function_Model></Dimap_Document>"
)


@pytest.fixture
def local(tmp_path: Path) -> Iterator[TestClient]:
    with make_client(tmp_path, compose_max_rows=5000) as c:
        yield c


def rpc_spec(name: str) -> dict[str, Any]:
    return {"images": [{"id": "A", "rpc": name, "measurements": ["m.csv"]}]}


BOUNDARY = b"pba-hostile-boundary"


def multipart(spec: str, files: list[tuple[str | bytes, bytes]]) -> bytes:
    """A multipart body written by hand: file names go out as raw bytes (httpx would
    percent-encode NUL and line ends)."""
    def part(disposition: bytes, data: bytes) -> bytes:
        return b"--" + BOUNDARY + b"\r\nContent-Disposition: form-data; " + disposition + b"\r\n\r\n" + data + b"\r\n"

    out = [part(b'name="spec"', spec.encode("utf-8", "surrogatepass"))]
    for name, data in files:
        raw = name if isinstance(name, bytes) else name.encode("utf-8", "surrogatepass")
        out.append(part(b'name="files"; filename="' + raw + b'"\r\nContent-Type: application/octet-stream', data))
    return b"".join(out) + b"--" + BOUNDARY + b"--\r\n"


def post_raw(c: TestClient, spec: str, files: list[tuple[str | bytes, bytes]]) -> Any:
    content_type = "multipart/form-data; boundary=" + BOUNDARY.decode()
    return c.post("/jobs/compose", content=multipart(spec, files), headers={"content-type": content_type})


# -- file names ----------------------------------------------------------------------------
@pytest.mark.parametrize(
    "name, code",
    [("a\x00_RPC.TXT", "invalid_file_name"), ("x" * 296 + "_RPC.TXT", "file_name_too_long"), ("\u00e9" * 130 + ".csv", "file_name_too_long"), ("a\nb.csv", "invalid_file_name")],
)
def test_hostile_file_names_are_located_422(local: TestClient, name: str, code: str) -> None:
    # the spec names the hostile file as an RPC (written to disk for GDAL): before, a NUL was
    # a ValueError and 300 characters an OSError, both a 500
    files = [(name, b"LINE_OFF: 1\n"), ("m.csv", b"point,line,column\n")]
    r = post_raw(local, json.dumps(rpc_spec(name)), files)
    if len(name) > 255:  # refused already as a name in the spec
        assert_problem(r, 422, "/spec/images/0/rpc")
        r = post_raw(local, json.dumps(rpc_spec("ok_RPC.TXT")), files)
    doc = assert_problem(r, 422, "/files/0")
    assert doc["errors"][0]["code"] == code


def test_an_upload_without_a_name_is_refused(local: TestClient) -> None:
    # multipart with filename="": refused (it passed on the landed main too: guards the check)
    r = local.post(
        "/jobs/compose",
        data={"spec": json.dumps(rpc_spec("a_RPC.TXT"))},
        files=[("files", ("", b"x", "text/plain"))],
    )
    assert r.status_code in (400, 422), r.text
    assert r.headers["content-type"].startswith("application/problem+json")


def test_an_empty_rpc_name_in_the_spec_is_refused(local: TestClient) -> None:
    # before: "rpc": "" was falsy and the image silently became an image of its camera
    spec = {"images": [{"id": "A", "rpc": "", "camera": "prism-nadir", "measurements": ["m.csv"]}]}
    assert_problem(post_raw(local, json.dumps(spec), [("m.csv", b"point,line,column\np,1,2\n")]), 422, "/spec/images/0/rpc")


def test_xml_that_gdal_half_reads_is_a_located_422(local: TestClient) -> None:
    doc = assert_problem(
        post_raw(local, json.dumps(rpc_spec("RPC_SPOT6.XML")), [("RPC_SPOT6.XML", HALF_RPC_XML), ("m.csv", b"point,line,column\n")]),
        422,
        "/files/RPC_SPOT6.XML",
    )
    assert "HEIGHT_OFF" in doc["errors"][0]["message"]


# -- nesting and fields --------------------------------------------------------------------
@pytest.mark.parametrize("depth", [40, 5000])
def test_a_deeply_nested_spec_is_a_located_4xx(local: TestClient, depth: int) -> None:
    spec = '{"images": [{"id": "A"}], "options": ' + "[" * depth + "]" * depth + "}"
    assert_problem(post_raw(local, spec, [("m.csv", b"x")]), 422, "/spec")


def test_a_deeply_nested_camera_file_is_a_located_422(local: TestClient) -> None:
    spec = {"images": [{"id": "A", "camera": "c", "measurements": ["m.csv"]}], "camera_files": ["c.json"]}
    files = [("c.json", b"[" * 100_000 + b"]" * 100_000), ("m.csv", b"point,line,column\np,1,2\n")]
    assert_problem(post_raw(local, json.dumps(spec), files), 422, "/files/c.json")


def test_a_csv_field_over_the_csv_module_limit_is_located(local: TestClient) -> None:
    spec = {"images": [{"id": "A", "camera": "prism-nadir", "measurements": ["m.csv"]}]}
    data = b"point,line,column\n" + b'"' + b"x" * 200_000 + b'",1,2\n'
    doc = assert_problem(post_raw(local, json.dumps(spec), [("m.csv", data)]), 422, "/files/m.csv")
    assert doc["errors"][0]["line"] == 2


# -- bounded work --------------------------------------------------------------------------
def test_a_header_of_many_columns_is_refused_before_parsing_rows(local: TestClient) -> None:
    spec = {"images": [{"id": "A", "camera": "prism-nadir", "measurements": ["m.csv"]}]}
    data = ",".join(f"c{i}" for i in range(100_000)).encode() + b"\n"
    doc = assert_problem(post_raw(local, json.dumps(spec), [("m.csv", data)]), 422, "/files/m.csv")
    assert doc["errors"][0]["code"] == "too_many_columns"


def test_repeated_references_are_bounded(local: TestClient) -> None:
    # before: one 3.8 kB file named 200 times in 64 images answered 200 after 20 s with 237 MB
    images = [{"id": f"I{k}", "camera": "prism-nadir", "measurements": [f"m{j}.csv" for j in range(5)]} for k in range(64)]
    files = [(f"m{j}.csv", b"point,line,column\np,1,2\n") for j in range(5)]
    assert_problem(post_raw(local, json.dumps({"images": images}), files), 422, "/spec")
    twice = {"images": [{"id": "A", "camera": "prism-nadir", "measurements": ["m0.csv", "m0.csv"]}]}
    assert_problem(post_raw(local, json.dumps(twice), files[:1]), 422, "/spec/images/0/measurements")


@pytest.mark.parametrize("role", ["measurements", "points"])
def test_rows_are_counted_before_parsing(local: TestClient, role: str) -> None:
    # compose_max_rows=5000 here: a 6000-line tie file or survey is refused with 413 before it
    # is read (before: a million tie rows answered after 67 s, a million-row survey after 38 s)
    image = {"id": "A", "camera": "prism-nadir", "measurements": ["m.csv"]}
    small = b"point,line,column\np,1,2\n"
    if role == "measurements":
        files = [("m.csv", b"point,line,column\n" + b"".join(b"t%d,1,2\n" % i for i in range(6000)))]
        spec: dict[str, Any] = {"images": [image]}
    else:
        survey = b"id,x,y,z,role\n" + b"".join(b"p%d,-51.1,-22.1,400,gcp\n" % i for i in range(6000))
        files = [("m.csv", small), ("s.csv", survey)]
        spec = {"images": [image], "points": ["s.csv"]}
    doc = assert_problem(post_raw(local, json.dumps(spec), files), 413)
    assert "5000" in doc["detail"]


def test_an_upload_over_the_row_limit_is_never_held_whole(local: TestClient, monkeypatch: pytest.MonkeyPatch) -> None:
    """Lines are counted in chunks before any upload is read whole (before: a 41 MB survey of a
    million rows was read, parsed and held, 1.42 GB still held after its 422)."""
    from starlette.datastructures import UploadFile  # what the multipart parser makes

    sizes: list[int] = []
    real = UploadFile.read

    async def read(self: Any, size: int = -1) -> bytes:
        sizes.append(size)
        return await real(self, size)

    monkeypatch.setattr(UploadFile, "read", read)
    spec = {"images": [{"id": "A", "camera": "prism-nadir", "measurements": ["m.csv"]}]}
    data = b"point,line,column\n" + b"".join(b"t%d,1,2\n" % i for i in range(6000))
    assert_problem(post_raw(local, json.dumps(spec), [("m.csv", data)]), 413)
    assert sizes and all(0 < size <= 1 << 20 for size in sizes), sizes


def test_max_job_observations_bounds_compose(tmp_path: Path) -> None:
    with make_client(tmp_path, max_job_observations=100) as c:
        spec = {"images": [{"id": "A", "camera": "prism-nadir", "measurements": ["m.csv"]}]}
        data = b"point,line,column\n" + b"".join(b"t%d,1,2\n" % i for i in range(200))
        doc = assert_problem(post_raw(c, json.dumps(spec), [("m.csv", data)]), 413)
        assert "100" in doc["detail"]


def test_the_example_still_composes(local: TestClient) -> None:
    r = upload(local, example_spec(), example_files())
    assert r.status_code == 200, r.text[:1000]


# -- property-based fuzz of the multipart endpoint -------------------------------------------
LAUGHS = (
    b'<?xml version="1.0"?><!DOCTYPE lolz [<!ENTITY lol "lol">'
    + b"".join(b'<!ENTITY lol%d "%s">' % (i, (b"&lol%d;" % (i - 1) if i > 1 else b"&lol;") * 10) for i in range(1, 10))
    + b']><Dimap_Document><Rational_Function_Model><Global_RFM><RFM_Validity><LONG_SCALE>&lol9;</LONG_SCALE>'
    b"</RFM_Validity></Global_RFM></Rational_Function_Model></Dimap_Document>"
)
SUFFIXES = ["_RPC.TXT", ".RPB", ".xml", ".csv", ".points", ".gcp", ".json", ".tif", ""]


def _contents() -> Any:
    from hypothesis import strategies as st

    return st.one_of(
        st.binary(max_size=2000),
        st.text(max_size=500).map(lambda t: t.encode("utf-8", "surrogatepass")),
        st.sampled_from([
            LAUGHS, HALF_RPC_XML, b"[" * 50_000, b'{"a":' * 3000 + b"1" + b"}" * 3000,
            b"point,line,column\n" + b'"' + b"x" * 140_000 + b'",1,2\n', b"\x00" * 100, "é,ü\n1,2".encode("latin-1"),
            ",".join(f"c{i}" for i in range(5000)).encode(),
        ]),
    )


def _names() -> Any:
    from hypothesis import strategies as st

    stems = st.one_of(st.text(max_size=40), st.sampled_from(["", "a" * 300, "a\x00b", "../../etc/passwd", "dim_x", "\ud800"]))
    return st.tuples(stems, st.sampled_from(SUFFIXES)).map(lambda t: t[0] + t[1])


def test_fuzz_the_multipart_endpoint(tmp_path: Path) -> None:
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    files = st.lists(st.tuples(_names(), _contents()), min_size=1, max_size=4)
    roles = st.sampled_from(["measurements", "rpc", "ephemeris", "attitude", "state", "gcps", "points", "asp_gcp", "camera_files"])

    with make_client(tmp_path, compose_max_rows=5000) as c:

        @settings(max_examples=60, derandomize=True, database=None, deadline=None, suppress_health_check=list(HealthCheck))
        @given(files=files, roles=st.lists(roles, min_size=4, max_size=4), raw_spec=st.one_of(st.none(), st.text(max_size=200), st.sampled_from(["[" * 3000, '{"images": 1}'])))
        def check(files: list[tuple[str, bytes]], roles: list[str], raw_spec: str | None) -> None:
            image: dict[str, Any] = {"id": "A", "camera": "prism-nadir", "measurements": []}
            spec: dict[str, Any] = {"images": [image]}
            for (name, _), role in zip(files, roles):
                if role == "measurements":
                    image["measurements"].append(name)
                elif role in ("rpc", "ephemeris", "attitude", "state"):
                    image[role] = name
                else:
                    spec.setdefault(role, []).append(name)
            text = raw_spec if raw_spec is not None else json.dumps(spec)
            r = post_raw(c, text, list(files))
            assert r.status_code < 500, (r.status_code, r.text[:500])
            if r.status_code >= 400:
                assert r.headers["content-type"].startswith("application/problem+json")

        check()
