"""Roll scripted experts out in the task suite, and record what they did (mp4 or rerun)."""

from __future__ import annotations

from collections.abc import Callable, Container, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mosaic_data.collection.schema import ACTION_NAMES
from mosaic_data.experts import make_expert
from mosaic_data.tasks import make_task_env
from mosaic_data.tasks.base import MosaicTaskEnv

SUCCESS_TARGET = 0.95
"""Fraction of successful expert episodes every variation must reach."""


@dataclass
class Episode:
    """One expert rollout: per-step states and actions, frames if recorded, and its outcome."""

    task: str
    robot: str
    variation: int
    seed: int
    description: str
    success: bool = False
    length: int = 0
    states: list[np.ndarray] = field(default_factory=list)
    actions: list[np.ndarray] = field(default_factory=list)
    frames: list[np.ndarray] = field(default_factory=list)
    successes: list[bool] = field(default_factory=list)
    """Per step: whether the goal was reached right after that step's action (LeRobot's ``next.success``)."""


def run_expert_episode(
    env: MosaicTaskEnv,
    seed: int,
    record_frames: bool = False,
    expert_variation: int | None = None,
    record_final_frame: bool = True,
    frame_steps: Container[int] | None = None,
    on_step: Callable[[Episode], None] | None = None,
) -> Episode:
    """Reset ``env`` to ``seed`` and let the expert act until success or the horizon.

    Frames are rendered only when ``record_frames`` is set: rendering is most of the cost on a CPU.
    With ``record_final_frame`` the frame after the last action is recorded too (one frame more than
    actions); datasets pair every frame with its action and leave it out. ``frame_steps`` restricts the
    recorded frames to those steps (a replay that needs only a few frames of a known episode).
    ``on_step(episode)`` is called after every step, once its frame, state, action and success are in
    ``episode`` (a writer can encode the frame while the simulation goes on).
    """
    env.reset_to_seed(seed)
    expert = make_expert(env, expert_variation)
    episode = Episode(env.task_name, env.robot_key, env.variation_index, seed, env.variation.description)
    for _ in range(env.horizon):
        if record_frames and (frame_steps is None or episode.length in frame_steps):
            episode.frames.append(env.render_agentview())
        episode.states.append(env.robot_state())
        action = expert.act()
        episode.actions.append(action)
        env.step(action)
        episode.length += 1
        episode.successes.append(env.check_success())
        episode.success = episode.successes[-1]
        if on_step is not None:
            on_step(episode)
        if episode.success:
            break
    if record_frames and record_final_frame and (frame_steps is None or episode.length in frame_steps):
        episode.frames.append(env.render_agentview())
    return episode


def expert_episodes(
    task: str, robot: str, variations: list[int], seeds: list[int], record_frames: bool = False
) -> Iterator[Episode]:
    """Episodes for every (variation, seed) pair, one environment per variation."""
    for variation in variations:
        env = make_task_env(task, variation, robot)
        try:
            for seed in seeds:
                yield run_expert_episode(env, seed, record_frames)
        finally:
            env.close()


def write_video(path: Path, episodes: list[Episode], fps: int = 20) -> None:
    """Concatenate the episodes' frames into one H.264 mp4."""
    import imageio.v3 as iio

    frames = [frame for episode in episodes for frame in episode.frames]
    if not frames:
        raise ValueError("no frames were recorded")
    path.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(path, np.stack(frames), plugin="pyav", fps=fps, codec="libx264")


def write_rerun(path: Path, episodes: list[Episode], fps: int = 20) -> None:
    """Save a rerun recording: camera, state and action curves, success, one timeline per episode step."""
    import rerun as rr
    import rerun.blueprint as rrb

    recording = rr.RecordingStream("mosaic_experts")
    blueprint = rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial2DView(origin="/camera", name="agentview"),
            rrb.Vertical(
                rrb.TimeSeriesView(origin="/action", name="action (target pose, gripper)"),
                rrb.TimeSeriesView(origin="/state", name="state"),
                rrb.TimeSeriesView(origin="/success", name="success"),
            ),
        ),
        collapse_panels=True,
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    recording.save(str(path), default_blueprint=blueprint)
    global_step = 0
    for index, episode in enumerate(episodes):
        recording.set_time("episode", sequence=index)
        recording.log("/episode", rr.TextDocument(
            f"{episode.task} / {episode.robot} / variation {episode.variation}: {episode.description} "
            f"(seed {episode.seed}, {'success' if episode.success else 'failure'} in {episode.length} steps)"
        ))
        for step in range(episode.length):
            recording.set_time("frame", sequence=global_step)
            recording.set_time("episode_step", sequence=step)
            if episode.frames:
                recording.log("/camera", rr.Image(episode.frames[step]))
            for name, value in zip(ACTION_NAMES, episode.actions[step]):
                recording.log(f"/action/{name}", rr.Scalars(float(value)))
            for name, value in zip(["x", "y", "z"], episode.states[step][:3]):
                recording.log(f"/state/{name}", rr.Scalars(float(value)))
            recording.log("/state/gripper_opening", rr.Scalars(float(episode.states[step][-1])))
            is_last = step == episode.length - 1
            recording.log("/success", rr.Scalars(float(episode.success and is_last)))
            global_step += 1
    recording.flush()
