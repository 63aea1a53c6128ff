"""Noise sensitivity Mks: the peak gain from each loop's measurement noise to the plant input.

For loop ``i`` of a cascade (others closed) the noise response is
``N_i = -C_i H_{i+1} / (1 + L_i)`` (:meth:`gaintune.verification.cascade.Cascade.loop_responses`
with ``noise=True``); for one loop it is ``-C S``. Mks is ``max_w |N_i(jw)|``:

* the sampled loop (the default analysis): on ``z = e^{jw dt}`` up to the Nyquist frequency,
  where the curve ends;
* the continuous loop: up to 1000 times the top of the margin band, where |L| is negligible,
  so ``|N_i|`` has reached the controller's high-frequency gain (Kp + Kd/Tf for a filtered PID).

The grid is log-spaced and refined twice around the largest value (the peak of a lightly
damped loop is narrow). :func:`noise_peaks` serves the exact verification;
:mod:`gaintune.verification.quick` takes its batched estimate on its own grid.
"""

from __future__ import annotations

import math

import numpy as np

from gaintune.plants.plant import LinearModel
from gaintune.verification.cascade import Cascade
from gaintune.verification.freqresp import DelayModel
from gaintune.verification.sampled import SampledPlant

__all__ = ["noise_peaks", "NOISE_BAND_EXTENSION"]

#: The continuous grid runs this far above the top of the margin band.
NOISE_BAND_EXTENSION = 1e3


def _responses(cas: Cascade, lin: LinearModel, w: np.ndarray, delay: DelayModel | None,
               sampled: SampledPlant | None) -> np.ndarray:
    s = 1j * w
    with np.errstate(all="ignore"):
        if sampled is not None:
            _, N = cas.noise_responses(s, lin, sampled=sampled)
        else:
            fac = delay.factor(s) if delay is not None else 1.0
            _, N = cas.noise_responses(s, lin, fac)
    return np.abs(N[:, 0, :])  # (n_loops, W)


def noise_peaks(cas: Cascade, lin: LinearModel, band: tuple[float, float], delay: DelayModel | None = None,
                sampled: SampledPlant | None = None, n_freq: int = 1000) -> list[tuple[float | None, float | None]]:
    """``(Mks, frequency)`` per loop for a one-member cascade; ``(None, None)`` for an LQ loop.

    ``band``: the (lo, hi) of the margin analysis. A loop whose noise response is unbounded on
    the grid (an unstable or marginal closed loop) reports ``inf``.
    """
    lo, hi = band
    hi = sampled.nyquist if sampled is not None else hi * NOISE_BAND_EXTENSION
    lo = min(lo, hi * 1e-6)
    w = np.logspace(math.log10(lo), math.log10(hi), n_freq)
    w[-1] = hi
    A = _responses(cas, lin, w, delay, sampled)
    out: list[tuple[float | None, float | None]] = []
    for i, lp in enumerate(cas.loops):
        if lp.kind != "pid":
            out.append((None, None))
            continue
        a = np.nan_to_num(A[i], nan=np.inf)
        j = int(np.argmax(a))
        best, wbest = float(a[j]), float(w[j])
        if math.isfinite(best):
            wl, wr = w[max(j - 1, 0)], w[min(j + 1, w.size - 1)]
            for _ in range(2):  # refine around the peak: 41 points between the neighbours, twice
                g = np.logspace(math.log10(wl), math.log10(wr), 41)
                ag = np.nan_to_num(_responses(cas, lin, g, delay, sampled)[i], nan=np.inf)
                k = int(np.argmax(ag))
                if ag[k] > best:
                    best, wbest = float(ag[k]), float(g[k])
                wl, wr = g[max(k - 1, 0)], g[min(k + 1, g.size - 1)]
        out.append((best, wbest))
    return out
