"""95% Wilson score intervals of success rates: how far from the true rate a rate measured on n episodes may be.

A rate from few episodes is coarse: 7 successes in 10 episodes fit any true rate from 40% to 89%, so two agents
10 points apart on 10 episodes are not told apart. The Wilson interval is used rather than mean +- 1.96
std / sqrt(n) because it stays inside [0, 1] and keeps its width at 0 or n successes, the usual outcomes of the
expert and untrained rows, where that approximation gives a width of zero. Every table of mosaic-eval and of the
experiment reports takes its interval from :func:`wilson_interval`.

n counts *instances*, the distinct episodes (task, variation, episode index) behind a rate. Checkpoints of one
row, and the seeds and checkpoints of an experiment cell, all replay the same held-out instances: pooling their
episodes would count each instance several times and give an interval too narrow by the square root of that.
The average of the outcomes on one instance lies in [0, 1], so their mean over n instances varies no more than
the mean of n 0/1 outcomes with the same rate: the Wilson interval on n trials does not understate how well the
instances pin the rate down. The spread between training seeds is another matter, shown by the tables' "+-".
"""

from __future__ import annotations

import math

Z_95 = 1.96
"""The normal quantile of a two-sided 95% interval."""


def wilson_interval(successes: float, episodes: float, z: float = Z_95) -> tuple[float, float] | None:
    """(low, high) of the success rate after ``successes`` in ``episodes`` trials; None without episodes (no rate).

    ``successes`` may be fractional: ``episodes`` times a rate averaged over checkpoints on the same episodes
    (``episodes`` too, as a sum of such averaged counts in :func:`paired_difference_interval`)."""
    if episodes == 0:
        return None
    if not 0 <= successes <= episodes:
        raise ValueError(f"{successes} successes in {episodes} episodes: successes must be between 0 and episodes")
    rate, spread = successes / episodes, z * z / episodes
    centre = (rate + spread / 2) / (1 + spread)
    half_width = z * math.sqrt(rate * (1 - rate) / episodes + spread / (4 * episodes)) / (1 + spread)
    # exact at the ends: 0 successes cannot rule out a rate of 0, n successes one of 1 (no rounding just inside)
    low = 0.0 if successes == 0 else max(0.0, centre - half_width)
    high = 1.0 if successes == episodes else min(1.0, centre + half_width)
    return low, high


def rate_interval(rate: float, instances: int) -> tuple[float, float] | None:
    """The interval of a success ``rate`` measured on ``instances`` distinct episodes (averaged over any
    checkpoints that replayed them); None without instances."""
    return wilson_interval(min(max(rate * instances, 0.0), instances), instances)


def interval_text(interval: tuple[float, float] | None, instances: int) -> str:
    """``"[48.1, 85.5] (n=20)"``: an interval in percent and the instances behind it; ``"(n=0)"`` without any."""
    if interval is None:
        return "(n=0)"
    low, high = interval
    return f"[{100 * low:.1f}, {100 * high:.1f}] (n={instances})"


def paired_difference_interval(
    both: float, after_only: float, before_only: float, neither: float, z: float = Z_95
) -> tuple[float, float] | None:
    """95% interval of ``after - before``, two success rates measured on the same episodes (Newcombe's hybrid score
    interval for paired data, his 1998 method 10); None without episodes.

    The two rates share their episodes, so their difference varies less than two independent rates would: only the
    episodes where exactly one of the two succeeded (``after_only``, ``before_only``) move it. The interval combines
    each rate's Wilson interval with the correlation of the paired outcomes (continuity-corrected towards 0 when
    positive), and stays inside [-1, 1]. Counts may be fractional: averaged over checkpoints that replayed the same
    instances, as :func:`rate_interval` takes them."""
    episodes = both + after_only + before_only + neither
    if episodes <= 0:
        return None
    after, before = (both + after_only) / episodes, (both + before_only) / episodes
    after_low, after_high = wilson_interval(min(both + after_only, episodes), episodes, z)
    before_low, before_high = wilson_interval(min(both + before_only, episodes), episodes, z)
    spread = (both + after_only) * (before_only + neither) * (both + before_only) * (after_only + neither)
    association = both * neither - after_only * before_only
    if association > 0:
        association = max(association - episodes / 2, 0.0)
    correlation = association / math.sqrt(spread) if spread > 0 else 0.0
    difference = after - before
    # each side of the difference combines one rate's distance to its lower bound with the other's to its upper one
    down, up = after - after_low, before_high - before
    below = math.sqrt(down * down - 2 * correlation * down * up + up * up)
    up, down = after_high - after, before - before_low
    above = math.sqrt(up * up - 2 * correlation * up * down + down * down)
    return max(-1.0, difference - below), min(1.0, difference + above)
