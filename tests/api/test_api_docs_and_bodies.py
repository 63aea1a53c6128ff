"""API rough edges a new user hits: /docs offline, body content types (415, YAML), the python export."""

from __future__ import annotations

import socket
import threading
import time
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from gaintune_api.main import create_app
from gaintune_api.settings import Settings

CHROMIUM = Path("/usr/bin/chromium")
BROWSER_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
                "--disable-sync", "--no-first-run"]
SPEC = {"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}],
        "scenario": {"dt": 0.05, "horizon": 20.0}, "search": {"budget": 200}}
SPEC_YAML = """\
plant: {tf: {num: [1], den: "(s+1)^3"}}
loops: [{type: pi}]
scenario: {dt: 0.05, horizon: 20.0}
search: {budget: 200}
"""


def _settings(tmp_path: Path, **kw) -> Settings:
    base = dict(db_path=tmp_path / "jobs.db", data_dir=tmp_path / "data", workers=0, warmup=False, compute_processes=0)
    base.update(kw)
    return Settings(_env_file=None, **base)


@pytest.fixture
def client(tmp_path):
    with TestClient(create_app(_settings(tmp_path)), raise_server_exceptions=False) as c:
        yield c


def test_body_without_json_content_type_is_415_naming_the_type(client):
    r = client.post("/v1/tune", content=b"plant: x", headers={"content-type": "text/plain"})
    assert r.status_code == 415, r.text
    body = r.json()
    assert "application/json" in body["detail"] and "application/yaml" in body["detail"]
    assert body["errors"][0]["loc"] == "header.content-type"
    r = client.post("/v1/verify", data={"a": "1"})  # a form post, as curl -d sends by default
    assert r.status_code == 415


def test_yaml_body_with_yaml_content_type_is_accepted(client):
    r = client.post("/v1/tune", content=SPEC_YAML.encode(), headers={"content-type": "application/yaml"})
    assert r.status_code == 202, r.text
    as_json = client.post("/v1/tune", json=SPEC)
    assert r.json()["spec_hash"] == as_json.json()["spec_hash"]  # the same spec, whichever way it was sent


def test_yaml_body_invalid_or_nan_is_400(client):
    r = client.post("/v1/tune", content=b"plant: [unclosed", headers={"content-type": "application/yaml"})
    assert r.status_code == 400 and "not valid YAML" in r.json()["detail"]
    bad = SPEC_YAML.replace("horizon: 20.0", "horizon: .nan")
    r = client.post("/v1/tune", content=bad.encode(), headers={"content-type": "application/x-yaml"})
    assert r.status_code == 400 and "finite" in r.json()["detail"]


def test_yaml_spec_field_errors_are_422_at_the_field(client):
    bad = SPEC_YAML.replace("budget: 200", "budget: -5")
    r = client.post("/v1/tune", content=bad.encode(), headers={"content-type": "application/yaml"})
    assert r.status_code == 422, r.text
    assert any(e["loc"].endswith("search.budget") for e in r.json()["errors"])


def test_openapi_offers_the_python_export(client):
    params = client.get("/openapi.json").json()["paths"]["/v1/jobs/{job_id}/export"]["get"]["parameters"]
    fmt = next(p for p in params if p["name"] == "format")
    assert "python" in str(fmt["schema"])


def test_docs_page_references_local_assets_only(client):
    html = client.get("/docs").text
    assert "cdn" not in html.lower() and "/static/docs/swagger-ui-bundle.js" in html
    assert client.get("/static/docs/swagger-ui-bundle.js").status_code == 200
    assert client.get("/static/docs/swagger-ui.css").status_code == 200
    redoc = client.get("/redoc").text
    assert "cdn" not in redoc.lower() and "/static/docs/redoc.standalone.js" in redoc
    assert client.get("/static/docs/redoc.standalone.js").status_code == 200


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def live_url(tmp_path):
    import uvicorn

    port = _free_port()
    server = uvicorn.Server(uvicorn.Config(create_app(_settings(tmp_path)), host="127.0.0.1", port=port,
                                           log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    for _ in range(600):  # bounded: the server binds within a few seconds even on a loaded machine
        if server.started:
            break
        time.sleep(0.05)
    assert server.started, "uvicorn did not start"
    yield f"http://127.0.0.1:{port}"
    server.should_exit = True
    thread.join(timeout=30)


@pytest.mark.browser
@pytest.mark.skipif(not CHROMIUM.exists(), reason="/usr/bin/chromium is not installed (apt-get install chromium)")
def test_docs_render_in_chromium_with_no_network(live_url):
    from playwright.sync_api import sync_playwright

    offhost: list[str] = []

    def only_localhost(route) -> None:  # the network is "off": anything but this server is refused
        if route.request.url.startswith(live_url):
            route.continue_()
        else:
            offhost.append(route.request.url)
            route.abort()

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=BROWSER_ARGS)
        try:
            page = browser.new_page()
            page.route("**/*", only_localhost)
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(f"{live_url}/docs")
            page.wait_for_selector(".swagger-ui .info .title", timeout=60_000)
            assert "gaintune API" in page.locator(".swagger-ui .info .title").inner_text()
            page.wait_for_selector(".opblock-summary-path", timeout=60_000)  # the operations rendered too
            assert page.locator(".opblock-summary-path").count() > 5
            assert errors == [] and offhost == []
        finally:
            browser.close()
