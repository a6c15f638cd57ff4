"""README documents every PBA_ setting and the server's quick start."""

from __future__ import annotations

from pathlib import Path

from service.settings import Settings

README = Path(__file__).resolve().parents[2] / "README.md"


def test_every_setting_is_in_the_readme_table() -> None:
    text = README.read_text()
    missing = [
        f"PBA_{name.upper()}"
        for name in Settings.model_fields
        if f"| `PBA_{name.upper()}` |" not in text
    ]
    assert not missing, f"README settings table lacks {missing}"


def test_quick_start_mentions_make_serve_and_make_test() -> None:
    text = README.read_text()
    assert "make serve" in text and "make test" in text and "http://127.0.0.1:8000" in text
