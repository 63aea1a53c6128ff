"""gaintune runs BLAS on one thread (tiny matrices: worker threads only cost), whatever was imported first."""

from __future__ import annotations

import json
import os
import subprocess
import sys

PROBE = """
import json, numpy
import gaintune
import scipy.linalg
from threadpoolctl import threadpool_info
print(json.dumps([(i["filepath"], i["num_threads"]) for i in threadpool_info() if i["user_api"] == "blas"]))
"""


def test_scipy_blas_loaded_after_gaintune_runs_one_thread_when_numpy_came_first():
    unset = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS")
    env = {k: v for k, v in os.environ.items() if k not in unset}
    out = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, check=True).stdout
    libs = json.loads(out.strip().splitlines()[-1])
    assert any("scipy" in path for path, _ in libs)
    assert all(n == 1 for _, n in libs), libs
