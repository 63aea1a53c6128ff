"""The interactive API docs (Swagger UI at ``/docs``, ReDoc at ``/redoc``) served with no CDN.

FastAPI's own pages load their JavaScript and CSS from a CDN, so they are blank on a machine with
no internet. The assets here come from the ``fastapi-offline`` package (Swagger UI 5, ReDoc 2),
served by this app under :data:`ASSETS_URL`.
"""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter, FastAPI, Request
from fastapi.openapi.docs import get_redoc_html, get_swagger_ui_html, get_swagger_ui_oauth2_redirect_html
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles

__all__ = ["DOCS_URL", "REDOC_URL", "OAUTH2_REDIRECT_URL", "ASSETS_URL", "install_docs"]

DOCS_URL = "/docs"
REDOC_URL = "/redoc"
OAUTH2_REDIRECT_URL = "/docs/oauth2-redirect"
ASSETS_URL = "/static/docs"

router = APIRouter(include_in_schema=False)


def _assets_dir() -> Path:
    import fastapi_offline  # a data package: its static/ folder holds the Swagger UI and ReDoc bundles

    return Path(fastapi_offline.__file__).parent / "static"


@router.get(DOCS_URL, response_class=HTMLResponse)
def swagger_ui(request: Request) -> HTMLResponse:
    """Swagger UI, served from local assets."""
    root = request.scope.get("root_path", "")
    app: FastAPI = request.app
    return get_swagger_ui_html(
        openapi_url=f"{root}{app.openapi_url}", title=f"{app.title} - Swagger UI",
        oauth2_redirect_url=f"{root}{OAUTH2_REDIRECT_URL}",
        swagger_js_url=f"{root}{ASSETS_URL}/swagger-ui-bundle.js", swagger_css_url=f"{root}{ASSETS_URL}/swagger-ui.css",
        swagger_favicon_url=f"{root}{ASSETS_URL}/favicon.png",
    )


@router.get(OAUTH2_REDIRECT_URL, response_class=HTMLResponse)
def swagger_ui_redirect() -> HTMLResponse:
    """Swagger UI's OAuth2 redirect page."""
    return get_swagger_ui_oauth2_redirect_html()


@router.get(REDOC_URL, response_class=HTMLResponse)
def redoc(request: Request) -> HTMLResponse:
    """ReDoc, served from local assets."""
    root = request.scope.get("root_path", "")
    app: FastAPI = request.app
    return get_redoc_html(openapi_url=f"{root}{app.openapi_url}", title=f"{app.title} - ReDoc",
                          redoc_js_url=f"{root}{ASSETS_URL}/redoc.standalone.js",
                          redoc_favicon_url=f"{root}{ASSETS_URL}/favicon.png", with_google_fonts=False)


def install_docs(app: FastAPI) -> set[str]:
    """Add the docs pages and their assets to ``app`` (built with ``docs_url=None, redoc_url=None``).

    Returns
    -------
    set of str
        The paths that expose the API description (for :class:`~gaintune_api.middleware.DocsAuth`).
    """
    app.include_router(router)
    app.mount(ASSETS_URL, StaticFiles(directory=_assets_dir()), name="docs-assets")
    return {p for p in (app.openapi_url, DOCS_URL, REDOC_URL, OAUTH2_REDIRECT_URL) if p}
