"""The FOTD fit's zero-static-gain test is relative to the path's own scale, not to 1."""

from __future__ import annotations

import pytest

from gaintune.classical.fotd import NoModelError, fit_fotd
from gaintune.lti.statespace import tf_to_ss


@pytest.mark.parametrize("k", [1.0, 1e-9, 1e-15])
def test_a_small_process_gain_is_not_a_zero_static_gain(k):
    """Regression: K = 1e-15 (a plant in small units) was 'zero static gain' against an absolute 1e-12, so
    'tune --quick' found no model and started from the search box."""
    m = fit_fotd(tf_to_ss([k], [60.0, 1.0]), delay=10.0)
    assert m.K == pytest.approx(k, rel=0.1) and m.T == pytest.approx(60.0)


def test_a_zero_at_the_origin_is_still_a_zero_static_gain_whatever_the_scale():
    for k in (1.0, 1e-15):
        with pytest.raises(NoModelError, match="zero static gain"):
            fit_fotd(tf_to_ss([k, 0.0], [60.0, 1.0]), delay=10.0)
