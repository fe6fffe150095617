"""The hold statistic (still control steps in an episode) that finds where a one-frame policy would stall."""

from __future__ import annotations

import numpy as np

from mosaic_data.collection.validate import HOLD_IGNORED_FIRST, HOLD_IGNORED_LAST, hold_warning, longest_hold


def moving_actions(steps: int) -> np.ndarray:
    """Actions whose position target moves 1 cm per step along x."""
    actions = np.zeros((steps, 7))
    actions[:, 0] = 0.01 * np.arange(steps)
    return actions


def test_longest_hold_counts_still_steps_between_the_ignored_ends():
    actions = moving_actions(60)
    assert longest_hold(actions) == (0, -1)
    actions[20:26, :3] = actions[20, :3]  # steps 21..25 repeat step 20's target
    actions[30:33, :3] = actions[30, :3] + np.array([0.001, 0.0, 0.0])  # within 2.5 mm: still
    assert longest_hold(actions) == (5, 21)


def test_holds_at_the_start_and_end_of_an_episode_are_not_counted():
    actions = moving_actions(40)
    actions[: HOLD_IGNORED_FIRST + 1, :3] = 0.0  # the arm leaving rest
    actions[-HOLD_IGNORED_LAST:, :3] = actions[-HOLD_IGNORED_LAST, :3]  # the goal reached
    assert longest_hold(actions) == (1, HOLD_IGNORED_FIRST)


def test_slow_moves_above_the_threshold_are_not_still():
    actions = moving_actions(40)
    actions[10:20, 0] = actions[10, 0] + 0.003 * np.arange(10)
    assert longest_hold(actions)[0] == 0


def test_hold_warning_names_the_longest_hold_past_a_policy_step():
    assert hold_warning({0: 2, 1: 5}) is None
    warning = hold_warning({0: 2, 1: 6, 2: 9})
    assert warning.startswith("2 episodes of 3 hold the hand still longer than a policy step")
    assert "longest: 9 steps in episode 2" in warning
