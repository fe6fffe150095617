"""The 95% Wilson interval behind every success table: published values, an independent solution of its defining
equation and SciPy's own Wilson interval agree with it; no episodes give no interval, not an error."""

from __future__ import annotations

import math

import pytest
from scipy.optimize import brentq
from scipy.stats import binomtest

from pipelines.evaluation.intervals import (
    Z_95,
    interval_text,
    paired_difference_interval,
    rate_interval,
    wilson_interval,
)

KNOWN = [  # (successes, episodes, low, high), 4 decimals, z = 1.96
    (0, 10, 0.0, 0.2775),
    (10, 10, 0.7225, 1.0),
    (8, 10, 0.4902, 0.9433),
    (14, 20, 0.4810, 0.8545),
    (5, 10, 0.2366, 0.7634),
    (1, 1, 0.2065, 1.0),
]


@pytest.mark.parametrize("successes, episodes, low, high", KNOWN)
def test_known_values(successes, episodes, low, high):
    assert wilson_interval(successes, episodes) == pytest.approx((low, high), abs=5e-5)


def _score_bounds(successes: int, episodes: int, z: float) -> tuple[float, float]:
    """The Wilson bounds by their definition: the true rates p whose score test |k/n - p| = z sqrt(p(1-p)/n) is
    just at the edge, found by root finding on either side of k/n."""
    rate = successes / episodes

    def score(p: float) -> float:
        return abs(rate - p) - z * math.sqrt(p * (1 - p) / episodes)

    low = 0.0 if successes == 0 else brentq(score, 1e-12, rate - 1e-12)
    high = 1.0 if successes == episodes else brentq(score, rate + 1e-12, 1 - 1e-12)
    return low, high


@pytest.mark.parametrize("episodes", [1, 3, 10, 20, 40, 360])
def test_matches_the_score_equation_and_scipy(episodes):
    for successes in sorted({0, 1, episodes // 3, episodes // 2, episodes - 1, episodes}):
        ours = wilson_interval(successes, episodes)
        assert ours == pytest.approx(_score_bounds(successes, episodes, Z_95), abs=1e-9)
        scipy_ci = binomtest(successes, episodes).proportion_ci(0.95, method="wilson")  # z = 1.95996...
        assert ours == pytest.approx((scipy_ci.low, scipy_ci.high), abs=2e-5)
        assert ours[0] <= successes / episodes <= ours[1]


def test_no_episodes_is_no_interval_and_bad_counts_are_refused():
    assert wilson_interval(0, 0) is None and rate_interval(0.0, 0) is None
    assert interval_text(None, 0) == "(n=0)"
    with pytest.raises(ValueError, match="between 0 and episodes"):
        wilson_interval(11, 10)


def test_a_rate_averaged_over_checkpoints_is_taken_on_its_instances():
    """Three checkpoints on the same 10 instances with 7, 8 and 9 successes: a rate of 0.8 on 10 trials, as
    wide as one checkpoint's 8/10, not the three times narrower 24/30."""
    assert rate_interval(24 / 30, 10) == pytest.approx(wilson_interval(8, 10))
    assert rate_interval(1.0, 10) == (wilson_interval(10, 10)[0], 1.0)


def test_the_text_is_percent_with_the_episodes():
    assert interval_text(wilson_interval(14, 20), 20) == "[48.1, 85.5] (n=20)"
    assert interval_text(wilson_interval(0, 10), 10) == "[0.0, 27.8] (n=10)"


def test_paired_difference_matches_the_published_newcombe_interval():
    """Fagerland, Lydersen and Laake (2014, Stat. Med.), airway hyper-responsiveness before and after stem cell
    transplantation, 21 children: 1 both, 1 after only, 7 before only, 12 neither; the difference -0.286 with the
    Newcombe hybrid score interval (-0.507, -0.026)."""
    low, high = paired_difference_interval(both=1, after_only=1, before_only=7, neither=12)
    assert (low, high) == pytest.approx((-0.507, -0.026), abs=5e-4)
    assert paired_difference_interval(1, 7, 1, 12) == pytest.approx((-high, -low))  # the sides swapped


def test_paired_difference_edges():
    assert paired_difference_interval(0, 0, 0, 0) is None
    low, high = paired_difference_interval(10, 0, 0, 10)  # no episode changed: an interval around 0
    assert low == pytest.approx(-high) and 0 < high < 0.15
    assert paired_difference_interval(0, 20, 0, 0)[1] == 1.0  # every episode gained: the bound stays at 1
    # the same rates on more instances pin the difference down more tightly
    assert paired_difference_interval(20, 8, 2, 10)[0] > paired_difference_interval(10, 4, 1, 5)[0]
