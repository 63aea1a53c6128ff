"""Luyben's BLT on Wood-Berry against the published settings, the ultimate-gain finder, and bad inputs."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import brentq

from gaintune.classical.blt import BltError, _closed_loop_stable, biggest_log_modulus, blt_tune, ultimate
from gaintune.classical.mimo_references import REFERENCES, WOOD_BERRY_REFERENCES
from gaintune.lti.mimo import TfEntry, TfMatrix
from gaintune.plants.quadtank import MIN_PHASE, linearise, operating_point


def fotd(K: float, T: float, L: float) -> TfEntry:
    return TfEntry(np.array([K]), np.array([T, 1.0]), L)


def wood_berry(sign: float = 1.0) -> TfMatrix:
    """Wood & Berry (1973), minutes: xD and xB from reflux R and steam S."""
    rows = ((fotd(12.8, 16.7, 1), fotd(-18.9, 21, 3)), (fotd(6.6, 10.9, 7), fotd(-19.4, 14.4, 3)))
    rows = tuple(tuple(TfEntry(sign * e.num, e.den, e.delay) for e in row) for row in rows)
    return TfMatrix(rows, inputs=("R", "S"), outputs=("xD", "xB"))


@pytest.fixture(scope="module")
def wb():
    return blt_tune(wood_berry())


def test_blt_reproduces_luybens_wood_berry_settings(wb):
    """Luyben 1986: loop 1 Kc 0.375, Ti 8.29 min; loop 2 Kc -0.075, Ti 23.6 min; F about 2.55."""
    l1, l2 = wb.loops
    assert (round(l1.kc, 3), round(l1.ti, 2)) == (0.375, 8.29)
    assert (round(l2.kc, 3), round(l2.ti, 1)) == (-0.075, 23.6)
    assert abs(wb.F - 2.55) < 0.01
    assert (l1.output, l1.input, l2.output, l2.input) == ("xD", "R", "xB", "S")
    assert wb.stable


def test_blt_agrees_with_the_published_reference_row(wb):
    row = next(r for r in WOOD_BERRY_REFERENCES if r.method == "BLT")
    for loop, published in zip(wb.loops, row.loops, strict=True):
        assert loop.kc == pytest.approx(published["Kc"], abs=0.0006)
        assert loop.ti == pytest.approx(published["Ti"], abs=0.06)
    assert wb.loops[0].gains() == pytest.approx({"Kp": wb.loops[0].kc, "Ki": wb.loops[0].kc / wb.loops[0].ti})


def test_f_iteration_converges_to_twice_the_loop_count(wb):
    """The peak L_cm is 2N = 4 dB at F, above it for tighter tuning and below it for looser."""
    assert wb.target_db == 4.0
    assert wb.lcm_db == pytest.approx(4.0, abs=1e-6)
    assert wb.iterations < 60
    G = wood_berry()
    ku = np.array([lp.ku for lp in wb.loops])
    pu = np.array([lp.pu for lp in wb.loops])
    w = np.geomspace(1e-4, 10, 4000)
    for F, above in ((wb.F * 0.98, True), (wb.F * 1.02, False)):
        peak, _ = biggest_log_modulus(G, (0, 1), ku / (2.2 * F), F * pu / 1.2, w)
        assert (peak > 4.0) == above


def test_wood_berry_ultimate_gains_match_the_closed_form():
    """K e^{-Ls}/(Ts+1): atan(wu T) + wu L = pi, Ku = sqrt(1 + (wu T)^2)/K."""
    for K, T, L in ((12.8, 16.7, 1.0), (-19.4, 14.4, 3.0)):
        wu = brentq(lambda w, T=T, L=L: np.arctan(w * T) + w * L - np.pi, 1e-9, np.pi / L)
        ku, pu = ultimate(fotd(K, T, L))
        assert ku == pytest.approx(np.sqrt(1 + (wu * T) ** 2) / K, rel=1e-9)
        assert pu == pytest.approx(2 * np.pi / wu, rel=1e-9)


def test_ultimate_of_a_third_order_lag_and_an_integrator_with_delay():
    """1/(s+1)^3: wu = sqrt 3, Ku = 8; e^{-s}/s: wu = pi/2, Ku = pi/2."""
    ku, pu = ultimate(TfEntry(np.array([1.0]), np.array([1.0, 3.0, 3.0, 1.0])))
    assert (ku, pu) == pytest.approx((8.0, 2 * np.pi / np.sqrt(3)), rel=1e-9)
    ku, pu = ultimate(TfEntry(np.array([1.0]), np.array([1.0, 0.0]), 1.0))
    assert (ku, pu) == pytest.approx((np.pi / 2, 4.0), rel=1e-9)


def test_reverse_acting_loops_get_negative_gains_and_the_same_detuning(wb):
    flipped = blt_tune(wood_berry(sign=-1.0))
    assert flipped.F == pytest.approx(wb.F, rel=1e-8)
    for a, b in zip(flipped.loops, wb.loops, strict=True):
        assert a.kc == pytest.approx(-b.kc, rel=1e-8)
        assert a.ti == pytest.approx(b.ti, rel=1e-8)


def test_pairing_by_input_name_follows_the_inputs(wb):
    """With the plant's input columns swapped, pairing xD with R and xB with S by name gives the same design."""
    G = wood_berry()
    swapped = TfMatrix(tuple((row[1], row[0]) for row in G.entries), inputs=("S", "R"), outputs=G.outputs)
    res = blt_tune(swapped, pairing=("R", "S"))
    assert res.F == pytest.approx(wb.F, rel=1e-8)
    assert [lp.input for lp in res.loops] == ["R", "S"]
    assert blt_tune(swapped, pairing=(1, 0)).F == pytest.approx(wb.F, rel=1e-8)


def test_a_non_square_plant_is_refused():
    G = wood_berry()
    wide = TfMatrix(tuple(row + (fotd(1.0, 1.0, 1.0),) for row in G.entries), inputs=("R", "S", "F"),
                    outputs=G.outputs)
    with pytest.raises(BltError, match="square plant") as err:
        blt_tune(wide)
    assert err.value.field == "plant"


def test_an_entry_without_a_phase_crossover_is_refused_naming_the_loop():
    """The quadruple tank's diagonal entries are first-order lags: no ultimate gain."""
    G = linearise(MIN_PHASE, operating_point(MIN_PHASE, 3.0, 3.0))
    with pytest.raises(BltError, match="never reaches -180 degrees") as err:
        blt_tune(G)
    assert err.value.field == "loops[0] (y1 <- v1)"


def test_a_state_space_plant_and_a_bad_target_are_refused():
    G = wood_berry()
    with pytest.raises(BltError, match="TfMatrix") as err:
        blt_tune(G.pade_ss(2))
    assert err.value.field == "plant"
    for bad in (0.0, -3.0, float("nan")):
        with pytest.raises(BltError, match="positive number of dB") as err:
            blt_tune(G, target_db=bad)
        assert err.value.field == "target_db"


def test_a_zero_paired_entry_is_refused_naming_the_loop():
    G = wood_berry()
    zero = TfEntry(np.array([0.0]), np.array([1.0]))
    G0 = TfMatrix(((G.entries[0][0], G.entries[0][1]), (G.entries[1][0], zero)), G.inputs, G.outputs)
    with pytest.raises(BltError, match="entry is zero") as err:
        blt_tune(G0)
    assert err.value.field == "loops[1] (xB <- S)"


@pytest.mark.parametrize("pairing, field, message", [
    (("R",), "pairing", "one input per output"),
    (("R", "R"), "pairing", "one loop only"),
    (("R", "steam"), "pairing[1]", "unknown input 'steam'"),
    ((0, 2), "pairing[1]", "out of range"),
    ((0, None), "pairing[1]", "input name or index"),
])
def test_bad_pairings_are_refused(pairing, field, message):
    with pytest.raises(BltError, match=message) as err:
        blt_tune(wood_berry(), pairing=pairing)
    assert err.value.field == field


def _rhp_closed_loop_poles(G: TfMatrix, kc: np.ndarray, ti: np.ndarray) -> float:
    """Generalised Nyquist on exact delays: Z = k/2 - D/pi for det(I + G K) with k = 2 integrators (PI loops).

    D is the phase change of det(I + G K)(jw) from w -> 0+ (asymptote -pi: det ~ c/s^2, c > 0 here)
    to w -> inf (arg 1 = 0).
    """
    w = np.geomspace(1e-7, 1e3, 400_000)
    GK = G.freqresp(w) * (kc * (1 + 1 / (ti * 1j * w[:, None])))[:, None, :]
    phase = np.unwrap(np.angle(np.linalg.det(np.eye(2) + GK)))
    phase -= 2 * np.pi * np.round((phase[0] + np.pi) / (2 * np.pi))  # the asymptote is -pi, not +pi
    assert abs(phase[0] + np.pi) < 1e-3 and abs(phase[-1] - 2 * np.pi * np.round(phase[-1] / (2 * np.pi))) < 1e-3
    return 1 - (phase[-1] - phase[0]) / np.pi


def test_ziegler_nichols_settings_on_wood_berry_are_unstable_and_blt_is_stable(wb):
    """Padé eigenvalues and a Nyquist count on exact delays agree: plain ZN per loop (F = 1) has 2 RHP poles."""
    ku = np.array([lp.ku for lp in wb.loops])
    pu = np.array([lp.pu for lp in wb.loops])
    kc, ti = np.array([lp.kc for lp in wb.loops]), np.array([lp.ti for lp in wb.loops])
    assert not _closed_loop_stable(wood_berry(), (0, 1), ku / 2.2, pu / 1.2)
    assert _rhp_closed_loop_poles(wood_berry(), ku / 2.2, pu / 1.2) == pytest.approx(2.0, abs=1e-3)
    assert _closed_loop_stable(wood_berry(), (0, 1), kc, ti)
    assert _rhp_closed_loop_poles(wood_berry(), kc, ti) == pytest.approx(0.0, abs=1e-3)


def test_every_reference_row_converts_to_parallel_gains():
    for row in REFERENCES:
        gains = row.gains()
        assert len(gains) == 2 and row.citation and row.source
        for g in gains:
            assert set(g) == ({"Kp", "Ki"} if row.form == "PI" else {"Kp", "Ki", "Kd"})
            assert np.sign(g["Kp"]) == np.sign(g["Ki"])
