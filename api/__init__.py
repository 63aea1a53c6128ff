"""gaintune REST API: FastAPI app (``api.main:app``), SQLite job store and worker processes."""
