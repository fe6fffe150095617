"""Evaluation's demonstrations in one expert pass: the frames rendered afterwards from the kept per-step states are
bit for bit the frames a camera took during the run (what a probe-then-replay renders), and a demonstration is the
two-pass reference's, field for field, with the expert run once per attempt."""

from __future__ import annotations

import numpy as np
import pytest

import mosaic_data.rollout as rollout
from mosaic_data.demos import Demonstration, record_demonstration
from mosaic_data.rollout import run_expert_episode
from pipelines.evaluation.demo_sources import DEMONSTRATOR, policy_frames

SEED = 50_000


@pytest.mark.parametrize("task", ["door", "pick_place", "nut_assembly", "stack_block", "press_button"])
def test_kept_frame_states_render_the_frames_the_camera_took(task_env_cache, task):
    """The first frame (after the reset), the last one a demonstration has, the one after the last action and two in
    between; pick_place, nut_assembly and stack_block move free objects, press_button lights a lamp (a model colour)
    during the episode. (Rendering is slow on a loaded CPU: a few frames, not all.)"""
    env = task_env_cache(task, DEMONSTRATOR)
    length = run_expert_episode(env, SEED).length
    steps = {0, 1, length // 2, length - 1, length}
    episode = run_expert_episode(env, SEED, record_frames=True, record_frame_states=True, frame_steps=steps)
    assert episode.success and episode.length == length and len(episode.frames) == len(steps)
    assert len(episode.frame_states) == length + 1
    later = env.render_frame_states([episode.frame_states[step] for step in sorted(steps)])
    different = [step for step, live, kept in zip(sorted(steps), episode.frames, later) if not np.array_equal(live, kept)]
    assert not different, f"frames {different} of {sorted(steps)} differ"
    assert np.array_equal(env.render_agentview(), episode.frames[-1]), "rendering the states left the scene as it was"
    if task == "press_button":
        assert not np.array_equal(episode.frame_states[0].geom_rgba, episode.frame_states[-1].geom_rgba), "a lamp lit"


def two_pass_demonstration(env, seed, pick_frames, attempts, retry_stride) -> Demonstration:
    """The reference demonstration in two passes: the expert runs without a camera to learn the length, then the
    same seed is replayed rendering the picked frames."""
    for attempt in range(attempts):
        demo_seed = seed + retry_stride * attempt
        probe = run_expert_episode(env, demo_seed)
        if not probe.success:
            continue
        indices = list(range(probe.length)) if pick_frames is None else [int(i) for i in pick_frames(probe.length)]
        wanted = sorted(set(indices))
        replay = run_expert_episode(env, demo_seed, record_frames=True, record_final_frame=False, frame_steps=set(wanted))
        assert replay.length == probe.length
        by_step = dict(zip(wanted, replay.frames, strict=True))
        return Demonstration(env.task_name, env.robot_key, env.variation_index, demo_seed, probe.length, indices,
                             np.stack([by_step[i] for i in indices]), attempt + 1)
    raise AssertionError("the reference found no demonstration")


@pytest.mark.parametrize("n_frames", [4, None], ids=["policy-frames", "all-frames"])
def test_a_demonstration_is_the_two_pass_one_with_one_expert_pass_per_attempt(task_env_cache, monkeypatch, n_frames):
    """The first seed is declared a failure (its expert runs to the horizon, shortened to 90 steps: the retry needs
    about 70), so the retry's seed counts too."""
    env = task_env_cache("door", DEMONSTRATOR, 2)
    monkeypatch.setattr(env, "horizon", 90)
    real_check = env.check_success
    monkeypatch.setattr(env, "check_success", lambda *a, **k: env.instance_seed != SEED and real_check(*a, **k))
    experts, steps = [], []
    real_make_expert, real_step = rollout.make_expert, env.step
    monkeypatch.setattr(rollout, "make_expert", lambda *a, **k: experts.append(1) or real_make_expert(*a, **k))
    monkeypatch.setattr(env, "step", lambda action: steps.append(1) or real_step(action))
    pick = policy_frames(n_frames)

    demo = record_demonstration(env, SEED, pick, retry_stride=7)
    assert (len(experts), len(steps)) == (2, env.horizon + demo.length), "one expert pass per attempt"

    experts.clear()
    reference = two_pass_demonstration(env, SEED, pick, attempts=5, retry_stride=7)
    assert len(experts) == 3, "the reference runs two passes"
    assert (demo.seed, demo.length, demo.attempts) == (reference.seed, reference.length, reference.attempts)
    assert (demo.seed, demo.attempts) == (SEED + 7, 2)
    assert (demo.task, demo.robot, demo.variation) == (reference.task, reference.robot, reference.variation)
    assert demo.frame_indices == reference.frame_indices
    assert len(demo.frame_indices) == (4 if n_frames else demo.length)
    assert demo.frames.shape == reference.frames.shape and demo.frames.dtype == np.uint8
    assert np.array_equal(demo.frames, reference.frames), "the same frames, bit for bit"
