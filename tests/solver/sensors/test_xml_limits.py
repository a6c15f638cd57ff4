"""The safe XML reader's limits (solver/sensors/xmlsafe.py), checked while the document streams.

The hostile files are those of a probe of the server: 2,000,000 nested elements (14 MB, no DTD),
one element with 1,000,000 attributes (12 MB), 3,000,000 empty elements (12 MB). Each must be
refused naming the element, in under 2 s of this process's CPU and under 100 MB of allocations
(tracemalloc sees expat's buffers: pyexpat allocates through Python's allocator). CPU time, not
wall time: the bound is the reader's work, whatever else the machine does.

Counts in a vendor file (``NUM...`` elements) are checked whether read or not: a ``NUMLISTS`` of
-5 in a real WorldView-2 XML is refused naming the element.
"""

from __future__ import annotations

import time
import tracemalloc
from pathlib import Path

import pytest

from solver.sensors import xmlsafe
from solver.sensors.errors import MetadataError
from solver.sensors.maxar import read_maxar, read_maxar_rpc

VENDOR = Path(__file__).resolve().parents[2] / "data" / "vendor" / "stereopipeline"
CPU_S, PEAK_BYTES = 2.0, 100 * 2**20


def _nested(n: int) -> bytes:
    return b"<a>" * n + b"</a>" * n


HOSTILE = {
    "nested": (lambda: _nested(2_000_000), "a", "nested deeper"),
    "attributes": (lambda: b"<root " + b" ".join(b'a%d="1"' % i for i in range(1_000_000)) + b"/>", "root", "tag longer"),
    "elements": (lambda: b"<r>" + b"<e/>" * 3_000_000 + b"</r>", "e", "more than"),
}


@pytest.mark.parametrize("case", list(HOSTILE))
def test_hostile_files_are_refused_fast_and_small(case, tmp_path):
    make, element, words = HOSTILE[case]
    data = make()
    assert len(data) > 11_000_000
    path = tmp_path / f"{case}.xml"
    path.write_bytes(data)
    del data
    for source in ("file", "bytes"):
        payload = path.read_bytes() if source == "bytes" else None
        # CPU timed without tracemalloc, which slows every allocation about fourfold (measured
        # 0.3 s of CPU for the elements case, 1.2 s traced); the allocations in a second read
        cpu = time.process_time()
        with pytest.raises(MetadataError) as info:
            xmlsafe.load(path, "hostile.xml", payload)
        cpu = time.process_time() - cpu
        tracemalloc.start()
        with pytest.raises(MetadataError):
            xmlsafe.load(path, "hostile.xml", payload)
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        assert info.value.element == element and words in str(info.value), str(info.value)
        assert cpu < CPU_S, f"{case} ({source}): {cpu:.2f} s of CPU"
        assert peak < PEAK_BYTES, f"{case} ({source}): {peak / 2**20:.0f} MB allocated"


def test_the_limits_sit_where_they_say(monkeypatch):
    """Depth 64 passes and 65 is refused; the element and attribute counts likewise."""
    assert xmlsafe.parse(_nested(xmlsafe.MAX_DEPTH), "ok").tag == "a"
    with pytest.raises(MetadataError, match="nested deeper"):
        xmlsafe.parse(_nested(xmlsafe.MAX_DEPTH + 1), "x")
    monkeypatch.setattr(xmlsafe, "MAX_ELEMENTS", 10)
    assert len(xmlsafe.parse(b"<r>" + b"<e/>" * 9 + b"</r>", "ok")) == 9
    with pytest.raises(MetadataError, match="more than 10 elements"):
        xmlsafe.parse(b"<r>" + b"<e/>" * 10 + b"</r>", "x")
    attrs = b" ".join(b'a%d="1"' % i for i in range(xmlsafe.MAX_ATTRIBUTES + 1))
    with pytest.raises(MetadataError, match="attributes on one element"):
        xmlsafe.parse(b"<r " + attrs + b"/>", "x")
    monkeypatch.setattr(xmlsafe, "MAX_TAG_BYTES", 1000)
    assert xmlsafe.parse(b"<r>" + b"x" * 5000 + b"</r>", "ok").text == "x" * 5000  # long text is not a long tag
    with pytest.raises(MetadataError, match="tag longer"):
        xmlsafe.parse(b'<r a="' + b"x" * 200_000 + b'"/>', "x")


def test_a_dtd_is_still_refused():
    with pytest.raises(MetadataError, match="DTD or entities"):
        xmlsafe.parse(b'<!DOCTYPE r [<!ENTITY a "aaaa">]><r>&a;</r>', "x")


@pytest.mark.parametrize("value", ["-5", "1e12", "2.5", "nan"])
def test_a_negative_or_absurd_count_is_refused_naming_the_element(value, tmp_path):
    """``NUMLISTS`` is not a field the reader uses: it is checked all the same."""
    text = (VENDOR / "wv_test1.xml").read_text()
    assert "<NUMLISTS>" not in text
    bad = tmp_path / "wv.xml"
    bad.write_text(text.replace("<NUMTLC>", f"<NUMLISTS>{value}</NUMLISTS><NUMTLC>", 1))
    for reader in (read_maxar, read_maxar_rpc):
        with pytest.raises(MetadataError) as info:
            reader(bad)
        assert info.value.element.endswith("/NUMLISTS"), info.value.element
        assert "count" in str(info.value)
    ok = tmp_path / "ok.xml"
    ok.write_text(text.replace("<NUMTLC>", "<NUMLISTS>3</NUMLISTS><NUMTLC>", 1))
    assert read_maxar(ok).model is not None
