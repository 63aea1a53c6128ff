"""The exact sampled-data MIMO verdict: the loop the MIMO simulator and the exports run at their dt."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from gaintune.export.coefficients import discrete_pid_tf
from gaintune.export.verdict import verdict_at_dt
from gaintune.spec import load_spec
from gaintune.verification import verify
from gaintune.verification.mimo import mimo_report
from gaintune.verification.mimo_loop import decentralised_pid, pid_entry

sys.path.insert(0, str(Path(__file__).resolve().parent))
from mimo_fixtures import blt_loops  # noqa: E402
from mimo_fixtures import wood_berry as wb_plant  # noqa: E402
from test_mimo_verdict import blt, wood_berry  # noqa: E402


def _two_lags(dt: float, sampled: bool = True, delay: float = 0.0, a=(1.0, 2.0)) -> dict:
    """Two decoupled first-order lags a_i/(s + a_i), each with a P loop; scenarios at ``dt``."""
    ss = {"A": [[-a[0], 0.0], [0.0, -a[1]]], "B": [[a[0], 0.0], [0.0, a[1]]], "C": [[1.0, 0.0], [0.0, 1.0]],
          "inputs": ["u1", "u2"], "outputs": ["y1", "y2"]}
    if delay:
        ss["input_delays"] = [delay, delay]
    return {"plant": {"ss": ss},
            "loops": [{"name": "a", "measure": "y1", "drives": "u1", "type": "p", "direction": "direct"},
                      {"name": "b", "measure": "y2", "drives": "u2", "type": "p", "direction": "direct"}],
            "scenarios": [{"dt": dt, "horizon": 10.0}],
            "requirements": {"gm_min_db": 1.0},
            "verify": {"sampled": sampled}}


def test_decoupled_first_order_lags_with_p_control_have_the_hand_derived_discrete_poles() -> None:
    """ZOH of a/(s + a) at dt: y[k+1] = e^{-a dt} y[k] + (1 - e^{-a dt}) u[k]; u = -K y gives the
    closed-loop pole z = e^{-a dt} - K (1 - e^{-a dt}), one per loop."""
    dt, K = 0.2, (1.5, 0.7)
    rep = verify(load_spec(_two_lags(dt)), {"a": {"Kp": K[0]}, "b": {"Kp": K[1]}}, nonlinear=False)
    assert rep.sampled and rep.dt == dt and rep.stability.domain == "z"
    want = sorted(math.exp(-a * dt) - k * (1 - math.exp(-a * dt)) for a, k in zip((1.0, 2.0), K, strict=True))
    got = sorted(p[0] for p in rep.stability.poles)
    assert np.allclose(got, want, atol=1e-12) and all(abs(p[1]) < 1e-12 for p in rep.stability.poles)
    assert rep.stability.spectral_radius == pytest.approx(max(abs(v) for v in want), abs=1e-12)


def test_mimo_export_verdict_uses_the_exact_sampled_loop_not_a_half_sample_delay() -> None:
    """1/(s + 1) with u = -5 y sampled at dt = 0.5: z = e^{-0.5} - 5 (1 - e^{-0.5}) = -1.36, unstable. The
    continuous loop with dt/2 = 0.25 s of delay (the former MIMO verdict) is stable up to K ~ 6.9, so
    an export at dt = 0.5 was stamped from a loop that is not the one the firmware runs."""
    gains = {"a": {"Kp": 5.0}, "b": {"Kp": 0.5}}
    spec = load_spec(_two_lags(0.01, a=(1.0, 1.0)))
    verdict, rep = verdict_at_dt(spec, gains, 0.5)
    assert verdict == "fail" and rep is not None
    assert rep["sampled"] is True and rep["dt"] == 0.5 and rep["stability"]["stable"] is False
    assert rep["reasons"][0] == "closed loop unstable (all loops closed)"
    assert any("sampled at dt 0.5" in n for n in rep["notes"])
    z = math.exp(-0.5) - 5.0 * (1 - math.exp(-0.5))
    assert rep["stability"]["spectral_radius"] == pytest.approx(abs(z), rel=1e-9)
    approx = verify(load_spec(_two_lags(0.5, sampled=False, a=(1.0, 1.0))), gains, nonlinear=False)
    assert approx.stability.stable and not approx.sampled  # the half-sample approximation misses it
    assert verdict_at_dt(spec, gains, 0.05)[0] == "pass"  # fast enough sampling: stable, GM > 1 dB


def test_sampled_mimo_figures_converge_to_the_continuous_ones_as_dt_shrinks() -> None:
    """Wood-Berry with BLT PI: the sampled Ms, disk margin and gain margins approach those of the
    continuous loop (no sampling delay) as dt falls; at a coarse dt the dt/2 approximation is close to
    the exact figures, but not equal."""
    def figures(dt: float, sampled: bool) -> np.ndarray:
        spec = wood_berry(mimo_ms_max=2.6, disk_margin_min=0.5)
        d = spec.model_dump(mode="json")
        d["verify"]["sampled"] = sampled
        for sc in d["scenarios"]:
            sc["dt"] = dt
        rep = verify(load_spec(d), blt(), nonlinear=False)
        assert rep.stability.stable and rep.sampled is sampled and rep.mimo is not None
        return np.array([rep.mimo.ms, rep.mimo.disk_input.alpha] + [f.gm_db for f in rep.loops[:2]])

    ref = mimo_report(wb_plant(), decentralised_pid(wb_plant(), blt_loops()), blt_loops())  # no sampling
    cont = np.array([ref.ms, ref.disk_input.alpha] + [f.gm_db for f in ref.input_breaks])
    err = [np.max(np.abs(figures(dt, True) / cont - 1)) for dt in (0.5, 0.1, 0.02)]
    assert err[0] > err[1] > err[2] and err[2] < 1e-2 and err[0] > 10 * err[2], err  # first order in dt
    half = figures(0.5, False)
    assert np.max(np.abs(half / figures(0.5, True) - 1)) < 0.05


def test_sampled_mimo_controller_is_the_exports_discrete_pid_law() -> None:
    """The sampled loop's controller is the continuous law at s = (1 - z^-1)/dt; that is exactly the
    export's discrete law (discrete_pid_tf), for every combination of terms."""
    dt = 0.01
    z = np.exp(1j * np.array([0.3, 5.0, 100.0, math.pi / dt]) * dt)
    for kp, ki, kd, tf in ((2.0, 0.5, 0.3, 0.05), (1.5, 0.2, 0.0, 0.0), (1.0, 0.0, 0.4, 0.1), (3.0, 0.0, 0.0, 0.0)):
        num, den = discrete_pid_tf({"Kp": kp, "Ki": ki, "Kd": kd, "Tf": tf, "b": 1.0, "c": 1.0}, dt)
        want = np.polyval(num, z) / np.polyval(den, z)
        assert np.allclose(pid_entry(kp, ki, kd, tf).response((1 - 1 / z) / dt), want)


def test_sampled_mimo_loop_with_a_fractional_delay_matches_the_modified_z_transform() -> None:
    """A 0.25-sample input delay (tau = 0.05, dt = 0.2) on a/(s + a): the sampled plant is
    (b0 z + b1) / (z (z - e^{-a dt})) with b0 = 1 - e^{-a (dt - tau)}, b1 = e^{-a (dt - tau)} - e^{-a dt};
    with u = -K y the closed-loop poles are the roots of z^2 + (K b0 - p) z + K b1."""
    dt, tau, K = 0.2, 0.05, 2.0
    rep = verify(load_spec(_two_lags(dt, delay=tau, a=(1.0, 1.0))), {"a": {"Kp": K}, "b": {"Kp": K}}, nonlinear=False)
    p = math.exp(-dt)
    b0, b1 = 1 - math.exp(-(dt - tau)), math.exp(-(dt - tau)) - p
    want = np.roots([1.0, K * b0 - p, K * b1])
    got = np.array([complex(*q) for q in rep.stability.poles])
    for w in want:  # each loop contributes the same pair
        assert np.sum(np.abs(got - w) < 1e-9) == 2


@pytest.mark.parametrize(("a3", "stable"), [(0.0, True), (0.5, False)])
def test_sampled_mimo_plant_mode_no_loop_reaches_is_left_out_or_fails_the_loop(a3: float, stable: bool) -> None:
    """A third state driven by an input no loop drives and measured by no loop: at s = 0 (z = 1) it is left out
    of the verdict with a note, as in the continuous count; unstable (z = e^{0.5 dt}) it fails the loop."""
    d = _two_lags(0.1)
    d["plant"]["ss"].update(A=[[-1.0, 0, 0], [0, -2.0, 0], [0, 0, a3]], B=[[1.0, 0, 0], [0, 2.0, 0], [0, 0, 1.0]],
                            C=[[1.0, 0, 0], [0, 1.0, 0]], inputs=["u1", "u2", "u3"])
    rep = verify(load_spec(d), {"a": {"Kp": 1.0}, "b": {"Kp": 1.0}}, nonlinear=False)
    assert rep.sampled and rep.stability.stable is stable
    word = "marginal" if stable else "unstable"
    assert any(n.startswith(f"{word} sampled plant mode(s)") for n in rep.stability.notes), rep.stability.notes


def test_stored_mimo_verdict_of_the_continuous_loop_does_not_vouch_for_the_sampled_loop() -> None:
    """A MIMO verdict stored from the continuous loop plus dt/2 (every MIMO verdict before the exact sampled
    loop; same spec, same hash) was returned as it was by the export at its own dt: these gains (Kp = 5
    on 1/(s + 1) at dt = 0.5) were stamped 'pass' though the sampled loop is unstable."""
    gains = {"a": {"Kp": 5.0}, "b": {"Kp": 0.5}}
    loose = {"gm_min_db": 1.0, "ms_max": 10.0, "pm_min_deg": 10.0}
    spec = load_spec({**_two_lags(0.5, a=(1.0, 1.0)), "requirements": loose})
    old = verify(load_spec({**_two_lags(0.5, sampled=False, a=(1.0, 1.0)), "requirements": loose}), gains,
                 nonlinear=False)
    assert old.verdict == "pass" and not old.sampled
    stored = old.model_copy(update={"spec_hash": spec.content_hash()})
    verdict, rep = verdict_at_dt(spec, gains, 0.5, stored=stored)
    assert verdict == "fail" and rep is not None and rep["sampled"] is True
    assert verdict_at_dt(spec, gains, 0.5, stored=verify(spec, gains, nonlinear=False))[0] == "fail"


def _wb_spec(**req: float):
    from gaintune.plants.library import load_model

    d = load_model("wood_berry").example_spec()
    d["requirements"] = {**d["requirements"], **req, "backoff": 0}
    return load_spec(d)


def test_lean_sampled_check_figures_equal_the_full_sampled_report() -> None:
    from gaintune.evaluation.evaluator import Evaluator
    from gaintune.verification.mimo_sampled_report import sampled_loop, sampled_report
    from gaintune.verification.mimo_spec import spec_loop

    spec = _wb_spec(mimo_ms_max=2.5, disk_margin_min=0.5, mimo_mt_max=3.0)
    ev = Evaluator(spec)
    full = ev.layout.from_dict({"xD": {"Kp": 0.375, "Ki": 0.375 / 8.29}, "xB": {"Kp": -0.075, "Ki": -0.075 / 23.6}})
    base, loop = sampled_loop(spec, ev.plant, spec_loop(spec, ev.plant, ev.layout, full))
    whole = sampled_report(base, loop)
    for needs in ({"ms"}, {"mt"}, {"disk"}, {"break", "break_ms", "break_mt", "break_disk"}):
        lean = sampled_report(base, loop, needs=needs)
        assert lean.stability.stable == whole.stability.stable
        if "ms" in needs:
            assert (lean.ms_input, lean.ms_output) == (whole.ms_input, whole.ms_output)
        if "mt" in needs:
            assert (lean.mt_input, lean.mt_output) == (whole.mt_input, whole.mt_output)
        if "disk" in needs:
            assert (lean.disk_input, lean.disk_output) == (whole.disk_input, whole.disk_output)
        if "break" in needs:
            assert lean.input_breaks == whole.input_breaks and lean.output_breaks == whole.output_breaks


def test_lean_break_figures_skip_only_the_peaks_no_requirement_reads() -> None:
    """The 110-gain check spent two thirds of its break peaks' zooms on Mt and disk peaks that no requirement
    read (the example asks GM, PM and Ms per break). A lean check zooms only the peaks its requirements name:
    those and every crossing figure equal the full report's; a skipped peak keeps its grid maximum (a lower
    bound, never above the zoomed value)."""
    from dataclasses import replace

    from gaintune.evaluation.evaluator import Evaluator
    from gaintune.verification.mimo_sampled_report import sampled_loop, sampled_report
    from gaintune.verification.mimo_spec import requirement_needs, spec_loop

    spec = _wb_spec()
    ev = Evaluator(spec)
    full = ev.layout.from_dict({"xD": {"Kp": 0.375, "Ki": 0.375 / 8.29}, "xB": {"Kp": -0.075, "Ki": -0.075 / 23.6}})
    base, loop = sampled_loop(spec, ev.plant, spec_loop(spec, ev.plant, ev.layout, full))
    needs = requirement_needs({"gm_min_db": 6.0, "pm_min_deg": 45.0, "ms_max": 2.0})
    assert needs == {"break", "break_ms"}
    whole, lean = sampled_report(base, loop), sampled_report(base, loop, needs=needs)
    for a, b in zip(whole.input_breaks + whole.output_breaks, lean.input_breaks + lean.output_breaks, strict=True):
        assert replace(b, mt=a.mt, mt_freq=a.mt_freq, disk_alpha=a.disk_alpha, disk_gm_db=a.disk_gm_db,
                       disk_pm_deg=a.disk_pm_deg, disk_freq=a.disk_freq) == a
        assert b.mt <= a.mt and b.disk_alpha >= a.disk_alpha
    assert any(b.mt < a.mt for a, b in zip(whole.input_breaks, lean.input_breaks, strict=True))


def test_search_constraint_judges_the_sampled_loop_the_verdict_judges() -> None:
    """Before, the search's MIMO constraint judged the continuous loop with a half-sample delay while the
    verdict judged the exact sampled loop: `bench mimo`'s optimum at BLT's own Ms (2.472) met the search's
    constraint and failed the verdict (sampled Ms 2.477). At dt = 1 min, BLT's gains have Ms 3.080 sampled
    and 3.024 continuous + dt/2: with Ms <= 3.05 the search must call them infeasible, as the verdict does."""
    from gaintune.evaluation.evaluator import Evaluator, mimo_requirement_scores

    spec = _wb_spec(mimo_ms_max=3.05)
    spec = spec.model_copy(update={"scenarios": [sc.model_copy(update={"dt": 1.0}) for sc in spec.scenarios]})
    ev = Evaluator(spec)
    rows = np.array([ev.layout.tuned_of(ev.layout.from_dict({"xD": {"Kp": 0.375 * k, "Ki": 0.375 * k / 8.29},
                                                             "xB": {"Kp": -0.075 * k, "Ki": -0.075 * k / 23.6}}))
                     for k in (0.8, 1.0)])
    violation, _ = mimo_requirement_scores(ev, rows)
    verdicts = [verify(spec, ev.layout.to_dict(ev.layout.full(r[None, :])[0]), nonlinear=False).verdict for r in rows]
    assert verdicts == ["pass", "fail"]
    assert violation[0] == 0.0 and violation[1] > 0.0


def test_sampled_plant_is_built_once_per_plant_not_once_per_candidate(monkeypatch) -> None:
    """The search's sampled check discretised the plant and trimmed its hidden modes again for every
    candidate: plant-only work. It is now kept per plant form; the figures are unchanged."""
    from gaintune.evaluation.evaluator import Evaluator, mimo_requirement_scores
    from gaintune.verification import mimo_sampled_report as msr

    spec = _wb_spec(mimo_ms_max=2.5)
    ev = Evaluator(spec)
    base = ev.layout.tuned_of(ev.layout.from_dict({"xD": {"Kp": 0.375, "Ki": 0.375 / 8.29},
                                                   "xB": {"Kp": -0.075, "Ki": -0.075 / 23.6}}))
    rows = base[None, :] * np.array([0.8, 0.9, 1.0, 1.1])[:, None]
    msr._CORES.clear()
    calls = []
    real = msr.sampled_core
    monkeypatch.setattr(msr, "sampled_core", lambda *a, **k: calls.append(1) or real(*a, **k))
    cached, _ = mimo_requirement_scores(ev, rows)
    assert len(calls) == 1
    msr._CORES.clear()
    fresh = [mimo_requirement_scores(Evaluator(spec), r[None, :])[0][0] for r in rows]
    np.testing.assert_array_equal(cached, fresh)
