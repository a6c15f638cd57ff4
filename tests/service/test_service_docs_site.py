"""The built documentation site (make docs) is served under /docs-site (service/app.py), and
nothing is mounted when it has not been built."""

from __future__ import annotations

from pathlib import Path

from fastapi.testclient import TestClient

from service.app import create_app
from service.settings import Settings


def _site(folder: Path) -> Path:
    (folder / "how-to").mkdir(parents=True)
    (folder / "index.html").write_text("<html><body>pushbroom-ba documentation</body></html>")
    (folder / "how-to" / "blunders.html").write_text("<html><body>Find blunders</body></html>")
    return folder


def test_a_built_site_is_served_under_docs_site(tmp_path: Path) -> None:
    site = _site(tmp_path / "site")
    settings = Settings(data_dir=tmp_path / "data", workers=0, log_format="text", docs_site_dir=site)
    with TestClient(create_app(settings)) as c:
        home = c.get("/docs-site/")
        assert home.status_code == 200 and "pushbroom-ba documentation" in home.text
        assert home.headers["content-type"].startswith("text/html")
        assert "Find blunders" in c.get("/docs-site/how-to/blunders.html").text
        assert c.get("/docs-site/missing.html").status_code == 404
        assert c.get("/docs-site/../pyproject.toml").status_code == 404  # nothing outside the folder
        assert c.get("/healthz").status_code == 200  # the API is unchanged beside it


def test_no_site_no_mount(tmp_path: Path) -> None:
    empty = tmp_path / "not-built"
    empty.mkdir()
    settings = Settings(data_dir=tmp_path / "data", workers=0, log_format="text", docs_site_dir=empty)
    assert settings.resolved_docs_site_dir is None
    with TestClient(create_app(settings)) as c:
        assert c.get("/docs-site/").status_code == 404
