"""``python -m gaintune_api --host 127.0.0.1 --port 8000 --workers 1``: run the API server."""

from __future__ import annotations

import argparse

from gaintune_api.main import serve


def main(argv: list[str] | None = None) -> None:
    """Parse the command line and serve the API (:func:`gaintune_api.main.serve`)."""
    ap = argparse.ArgumentParser(prog="python -m gaintune_api", description="gaintune REST API server")
    ap.add_argument("--host", default="127.0.0.1")
    ap.add_argument("--port", type=int, default=8000)
    ap.add_argument("--workers", type=int, default=1, help="job worker processes (max concurrent jobs)")
    ap.add_argument("--log-level", default=None)
    args = ap.parse_args(argv)
    serve(args.host, args.port, args.workers, log_level=args.log_level)


if __name__ == "__main__":
    main()
