"""LQR / LQI state feedback.

Control law on the deviation from the operating point, x~ = x - x0::

    u = u0 - K x~ + Nr*(r - y0) + Kint * z,   dz/dt = r - y   (LQI only)

For ``lq_mode: weights`` the tuned gains are the diagonal of Q (``q_<state>``,
``q_int``) and R (``r``), and K comes from :func:`control.lqr` on the linearised
plant (augmented with the integral of the tracking error for LQI). For
``lq_mode: gains`` the entries of K are tuned directly. Without integral
action, Nr = -1/(C (A - B K)^-1 B) gives zero steady-state error on the
nominal plant.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gaintune.errors import GainError
from gaintune.plants.plant import LinearModel
from gaintune.spec import LoopSpec

__all__ = ["LqGains", "lq_gains"]


@dataclass(frozen=True)
class LqGains:
    """State-feedback gains of one LQ loop: ``u = u0 - K x~ + Nr (r - y0) + Kint z`` (module docstring)."""

    K: np.ndarray  # (n,) state feedback on x - x0
    Kint: float  # gain on the integral of r - y (0 for LQR)
    Nr: float  # reference feedforward (0 for LQI)


def lq_gains(loop: LoopSpec, gains: dict[str, float], lin: LinearModel, out_idx: int) -> LqGains:
    """State-feedback gains for one LQ loop on the linearised plant ``lin`` measuring output ``out_idx``."""
    import control

    A, B = lin.A, lin.B
    C = lin.C[out_idx : out_idx + 1, :]
    n = A.shape[0]
    lqi = loop.type == "lqi"
    if loop.lq_mode == "weights":
        q = [gains[f"q_{s}"] for s in lin.states]
        if lqi:
            Aa = np.block([[A, np.zeros((n, 1))], [-C, np.zeros((1, 1))]])
            Ba = np.vstack([B, np.zeros((1, 1))])
            q = q + [gains["q_int"]]
        else:
            Aa, Ba = A, B
        try:
            Ka, _, _ = control.lqr(Aa, Ba, np.diag(q), np.array([[gains["r"]]]))
        except Exception as exc:  # python-control raises several types for unstabilisable pairs
            raise GainError(f"{loop.name}", f"LQR has no stabilising solution for these weights: {exc}") from None
        Ka = np.asarray(Ka).ravel()
        K = Ka[:n]
        kint = -Ka[n] if lqi else 0.0
    else:
        K = np.array([gains[f"k_{s}"] for s in lin.states])
        kint = gains.get("k_int", 0.0) if lqi else 0.0
    nr = 0.0
    if not lqi:
        acl = A - B @ K.reshape(1, n)
        try:
            dc = float(-(C @ np.linalg.solve(acl, B))[0, 0])
        except np.linalg.LinAlgError:
            dc = 0.0
        nr = 1.0 / dc if abs(dc) > 1e-12 else 0.0
    return LqGains(K, float(kint), float(nr))
