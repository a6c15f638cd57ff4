"""The registry of vendor metadata readers (solver/sensors/readers.py): a new format is its module
and one registry line. The fake format below (a vendor that wraps Maxar's support data in a
``<fakesensor>`` root) is written the way a new module would be: a product class, a reader, the
product's source for the job fragment and its located points for the self-check, referenced by
"module:function"; its registry line is put in by ``monkeypatch``. Without touching another
file it is recognised and read (from disk and from an upload's bytes), turned into a job
fragment, self-checked, listed in the messages, and described to the web page's job builder
(``GET /jobs/compose/formats``); without the line it is refused, naming the formats read.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from tolerances import SAME_NUMBER_REL

from solver.sensors import readers
from solver.sensors.errors import MetadataError
from solver.sensors.formats import read_product
from solver.sensors.job_fragment import fragment, maxar_source
from solver.sensors.maxar import MaxarProduct, read_maxar
from solver.sensors.self_check import maxar_points, self_check, vendor_points

DATA = Path(__file__).parents[2] / "data" / "vendor" / "stereopipeline"
MODULE = __name__  # the fake module's functions are named "module:function", as a real one's


@dataclass
class FakeProduct:
    """The fake vendor's product: Maxar's support data under another root."""

    inner: MaxarProduct

    @property
    def model(self) -> Any:
        return self.inner.model

    @property
    def file(self) -> str:
        return self.inner.file

    @property
    def screening(self) -> Any:  # what the reading repaired or noted (solver.sensors.screening)
        return self.inner.screening

    @property
    def rpc(self) -> Any:  # the vendor's RPC in the file, which the self-check compares with
        return self.inner.rpc


def fake_read(request: readers.ReadRequest) -> FakeProduct:
    data = request.data.replace(b"<fakesensor>", b"<isd>").replace(b"</fakesensor>", b"</isd>")
    return FakeProduct(read_maxar(request.path, request.shown, data))


def fake_source(product: FakeProduct):  # noqa: ANN201 (SensorSource)
    return maxar_source(product.inner)


def fake_points(product: FakeProduct):  # noqa: ANN201
    points, notes = maxar_points(product.inner)
    return points, notes + ["fake vendor"]


FAKE = readers.Reader(
    "fake", "the fake vendor's XML (root fakesensor)", lambda head: b"<fakesensor>" in head, fake_read, (FakeProduct,),
    f"{MODULE}:fake_source", f"{MODULE}:fake_points", ("fakesensor",), ("fake_*.xml",),
)


@pytest.fixture
def with_fake(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(readers, "READERS", (*readers.READERS, FAKE))  # the one registry line


@pytest.fixture
def fake_file(tmp_path: Path) -> Path:
    text = (DATA / "wv_test1.xml").read_bytes().replace(b"<isd>", b"<fakesensor>").replace(b"</isd>", b"</fakesensor>")
    assert b"<fakesensor>" in text[:4096]
    path = tmp_path / "fake_wv1.xml"
    path.write_bytes(text)
    return path


def test_every_registered_reader_names_functions_that_exist() -> None:
    for reader in readers.READERS:
        for ref in (reader.source, reader.points):
            if ref is not None:
                assert callable(readers._function(ref)), (reader.name, ref)
    assert {r.name for r in readers.READERS} == {"maxar", "dimap-v1", "dimap-v2", "phr-dimap", "inpe-cbers"}


def test_a_fake_format_is_read_fragmented_checked_and_described(with_fake: None, fake_file: Path) -> None:
    product = read_product(fake_file)
    assert isinstance(product, FakeProduct) and readers.reader_of(product) is FAKE
    uploaded = read_product("fake_wv1.xml", "fake_wv1.xml", fake_file.read_bytes())  # an upload's bytes
    assert isinstance(uploaded, FakeProduct)

    # the job fragment: the same as the Maxar file's (the fake wraps it), but the file it names
    fake_doc = fragment([product], ["F"])
    maxar_doc = fragment([read_maxar(DATA / "wv_test1.xml")], ["F"])
    assert fake_doc["cameras"] == maxar_doc["cameras"]
    (fake_image,), (maxar_image,) = fake_doc["images"], maxar_doc["images"]
    assert fake_image["sensor"]["file"] == str(fake_file)
    assert {k: v for k, v in fake_image.items() if k != "sensor"} == {k: v for k, v in maxar_image.items() if k != "sensor"}

    # the self-check's located points come from the fake's own function
    points, notes = vendor_points(product)
    assert notes[-1] == "fake vendor" and len(points) == len(maxar_points(product.inner)[0])
    # the whole self-check (pba check-sensor, pba import-sensor) of the fake: the Maxar file's rows
    # (the same model and points; the job form composed through the fake's registered source)
    fake_check, maxar_check = self_check(product), self_check(product.inner)
    assert "fake vendor" in fake_check.notes and fake_check.passed == maxar_check.passed
    assert [(r.reference, r.model, r.points) for r in fake_check.rows] == [(r.reference, r.model, r.points) for r in maxar_check.rows]
    assert any(r.model == "job form" for r in fake_check.rows)
    for f, m in zip(fake_check.rows, maxar_check.rows):  # one computation twice: the same numbers
        assert f.rms_px == pytest.approx(m.rms_px, rel=SAME_NUMBER_REL, abs=1e-12)

    # the builder learns it: its root and file name in the description the server gives
    described = {f["name"]: f for f in readers.describe()}
    assert described["fake"]["roots"] == ["fakesensor"] and described["fake"]["file_names"] == ["fake_*.xml"]
    assert "the fake vendor's XML (root fakesensor)" in readers.formats_text()


def test_without_the_registry_line_the_fake_is_refused(fake_file: Path) -> None:
    with pytest.raises(MetadataError, match="not a sensor metadata file we read: Maxar"):
        read_product(fake_file)


def test_the_server_describes_the_registered_formats_to_the_builder(with_fake: None, tmp_path: Path) -> None:
    from fastapi.testclient import TestClient

    from service.app import create_app
    from service.settings import Settings

    app = create_app(Settings(data_dir=tmp_path, workers=0, log_format="text"))
    with TestClient(app) as client:
        r = client.get("/jobs/compose/formats")
    assert r.status_code == 200
    names = [f["name"] for f in r.json()["sensor"]]
    assert names == [reader.name for reader in readers.READERS] and "fake" in names
