"""gaintune REST API: FastAPI app (``gaintune_api.main:app``), SQLite job store and worker processes."""
