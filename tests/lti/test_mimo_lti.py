"""The shared MIMO LTI forms: exact frequency response against python-control, Padé realisations close to it."""

import control as ct
import numpy as np

from gaintune.lti.mimo import DelayedSS, TfEntry, TfMatrix


def _e(num, den, delay=0.0):
    return TfEntry(np.array(num, float), np.array(den, float), delay)


WOOD_BERRY = TfMatrix(
    ((_e([12.8], [16.7, 1], 1), _e([-18.9], [21, 1], 3)), (_e([6.6], [10.9, 1], 7), _e([-19.4], [14.4, 1], 3))),
    ("reflux", "steam"), ("xD", "xB"),
)


def test_tf_matrix_response_matches_python_control_entry_by_entry():
    w = np.logspace(-3, 1, 40)
    G = WOOD_BERRY.freqresp(w)
    ref = ct.tf([12.8], [16.7, 1])(1j * w) * np.exp(-1j * w * 1.0)
    assert np.allclose(G[:, 0, 0], ref)
    assert np.allclose(WOOD_BERRY.dcgain(), [[12.8, -18.9], [6.6, -19.4]])


def test_pade_realisation_of_wood_berry_matches_the_exact_response_at_low_frequency():
    w = np.logspace(-3, -0.5, 30)
    ss = WOOD_BERRY.pade_ss(8)
    assert ss.shape == (2, 2)
    assert np.abs(ss.freqresp(w) - WOOD_BERRY.freqresp(w)).max() < 1e-3


def test_delayed_ss_input_and_output_delays_multiply_the_columns_and_rows():
    A = np.array([[-1.0, 0.0], [0.0, -2.0]])
    sys = DelayedSS(A, np.eye(2), np.eye(2), np.zeros((2, 2)), ("u1", "u2"), ("y1", "y2"),
                    input_delays=np.array([0.5, 0.0]), output_delays=np.array([0.0, 0.25]))
    w = np.array([0.3, 2.0])
    G = sys.freqresp(w)
    s = 1j * w
    assert np.allclose(G[:, 0, 0], np.exp(-0.5 * s) / (s + 1))
    assert np.allclose(G[:, 1, 1], np.exp(-0.25 * s) / (s + 2))
    pade = sys.pade_ss(6)
    assert np.abs(pade.freqresp(w) - G).max() < 1e-6
    assert np.allclose(sys.dcgain(), np.diag([1.0, 0.5]))
