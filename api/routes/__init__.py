"""One router per resource: jobs (and POST /v1/tune), verify, simulate, plants, ops (health, metrics)."""
