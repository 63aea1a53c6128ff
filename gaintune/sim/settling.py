"""Whether a response has settled by the end of its scenario, and what horizon would let it.

A scenario whose horizon ends before the closed loop settles hides the slow part of the
response from the cost: a slow integral action looks free. :func:`unsettled_scenarios`
simulates the gains once per scenario (nominal plant, measurement noise off) and reads the
outer loop's error ``e = setpoint - output`` after the scenario's last event:

* **peak**: the largest ``|e|`` after the last event;
* **left**: ``|e|`` at the end.

The response has not settled when ``|e|`` over the last :data:`TAIL` of the scenario
exceeds ``SETTLE_BAND x peak``. The horizon that would do is the larger of the horizon
derived from the plant (:func:`gaintune.classical.timescale.plant_scale`: what a re-tune
needs to see the whole response) and, if ``|e|`` still decays (its mean over the last
:data:`TAIL` is below that of the window :data:`LOOKBACK` earlier), the time an exponential
through both windows reaches the band (what these gains need). If it does not decay, a
longer horizon would not remove it (a steady offset: no integral action, a saturated
actuator, or a ramp the loop cannot follow).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Unsettled", "unsettled_scenarios", "settling_messages", "SETTLE_BAND", "TAIL", "LOOKBACK"]

#: Settled: the error left is within this fraction of its peak.
SETTLE_BAND = 0.02
#: Fraction of the time after the last event read as the end of the response.
TAIL = 0.05
#: Fraction of that time between the two windows compared for decay.
LOOKBACK = 0.2


@dataclass(frozen=True)
class Unsettled:
    """A scenario whose response has not settled by its end."""

    scenario: str
    horizon: float
    left: float
    peak: float
    #: Estimated horizon (s) at which the error reaches the band; None when it does not decay.
    need: float | None

    def message(self, index: int, derived: float | None = None) -> str:
        """One line naming the scenario, the error left and the horizon that would do."""
        head = (f"scenario {self.scenario!r} has not settled by its end (horizon {self.horizon:.4g} s): the error left "
                f"is {self.left:.3g} ({100 * self.left / self.peak:.0f} % of its peak {self.peak:.3g})")
        if self.need is None:
            return (head + "; it does not decay, so a longer horizon will not remove it (no integral action, a "
                    "saturated actuator, or a ramp the loop cannot follow)")
        want = max(self.need, derived or 0.0)
        src = ("derived from the plant" if want == derived
               else f"where the error's decay reaches {100 * SETTLE_BAND:g} %")
        return (head + f"; a horizon of about {want:.3g} s ({src}) would cover it: set scenarios[{index}].horizon: "
                f"{want:.3g}, or leave dt/horizon out and let gaintune derive them")


def _window_mean(a: np.ndarray, stop: int, width: int) -> float:
    return float(np.mean(a[max(stop - width, 0):stop])) if stop > 0 else math.inf


def _read(name: str, t_end: float, k0: int, e: np.ndarray) -> Unsettled | None:
    """The verdict on one error trace ``e`` (after-event start index ``k0``), None when settled."""
    a = np.abs(e[k0:])
    if a.size < 4 or not np.all(np.isfinite(a)):
        return None  # too short to judge, or diverged (reported by the nonlinear check)
    peak = float(a.max())
    w = max(int(TAIL * a.size), 1)
    if not peak > 0 or a[-w:].max() <= SETTLE_BAND * peak:
        return None
    left = float(a[-1])
    back = max(int(LOOKBACK * a.size), 1)
    m_end, m_before = _window_mean(a, a.size, w), _window_mean(a, a.size - back, w)
    need = None
    if 0 < m_end < m_before * (1 - 1e-3):
        dt = t_end / len(e)
        tau = back * dt / math.log(m_before / m_end)
        need = t_end + tau * max(math.log(m_end / (SETTLE_BAND * peak)), 0.0)
    return Unsettled(name, t_end, left, peak, need)


def unsettled_scenarios(sim, full_gains: np.ndarray) -> list[tuple[int, Unsettled]]:
    """``(index, Unsettled)`` for every scenario of ``sim.spec`` whose response to ``full_gains`` has not settled.

    Parameters
    ----------
    sim
        A :class:`gaintune.sim.Simulator` (its spec resolved: every dt and horizon a number).
    full_gains
        One full gain vector (layout order).
    """
    full = np.atleast_2d(np.asarray(full_gains, dtype=float))[:1]
    outer = sim.spec.loops[0].name
    out = []
    for i, sc in enumerate(sim.spec.scenarios):
        quiet = sc.model_copy(update={"noise_std": 0.0}) if sc.noise_std else sc
        res = sim.run(full, None, quiet, traces=True)
        e = res.traces[f"sp.{outer}"][0] - res.traces[f"y.{outer}"][0]
        k0 = min(int(round(sc.last_event() / sc.dt)), len(e) - 1)
        found = _read(sc.name, sc.n_steps * sc.dt, k0, e)
        if found is not None:
            out.append((i, found))
    return out


def settling_messages(sim, full_gains: np.ndarray) -> list[str]:
    """One warning per unsettled scenario (:meth:`Unsettled.message`), with the horizon derived from the plant."""
    from gaintune.classical.timescale import plant_scale
    from gaintune.errors import GaintuneError

    found = unsettled_scenarios(sim, full_gains)
    if not found:
        return []
    try:
        derived = plant_scale(sim.spec, sim.plant).horizon
    except GaintuneError:
        derived = None
    return [u.message(i, None if derived is None else derived + sim.spec.scenarios[i].last_event()) for i, u in found]
