"""Roll scripted experts out in the task suite, and record what they did (mp4 or rerun)."""

from __future__ import annotations

from collections.abc import Callable, Container, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mosaic_data.action_noise import ActionNoise
from mosaic_data.collection.schema import ACTION_NAMES
from mosaic_data.experts import make_expert
from mosaic_data.tasks import make_task_env
from mosaic_data.tasks.base import MosaicTaskEnv
from mosaic_data.tasks.rendering import FrameState

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
    """The expert's actions; with ``action_noise`` the environment executed perturbed copies of them."""
    frames: list[np.ndarray] = field(default_factory=list)
    frame_states: list[FrameState] = field(default_factory=list)
    """What each frame shows, to render it later (``record_frame_states``; one per frame, as ``frames``)."""
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
    record_frame_states: bool = False,
    action_noise: ActionNoise | None = None,
) -> Episode:
    """Reset ``env`` to ``seed`` and let the expert act until success or the horizon.

    Frames are rendered only when ``record_frames`` is set: rendering is most of the cost on a CPU.
    With ``record_final_frame`` the frame after the last action is recorded too (one frame more than
    actions); datasets pair every frame with its action and leave it out. ``frame_steps`` restricts the
    recorded frames to those steps (a replay that needs only a few frames of a known episode).
    ``on_step(episode)`` is called after every step, once its frame, state, action and success are in
    ``episode`` (a writer can encode the frame while the simulation goes on).
    ``record_frame_states`` keeps, for every frame (the same steps as ``record_frames`` with
    ``record_final_frame``), what :meth:`MosaicTaskEnv.render_frame_states` needs to render it identically
    later: a pass that learns which frames it wants only at its end renders just those.
    ``action_noise`` (DART, :mod:`mosaic_data.action_noise`): the environment executes each expert action with noise
    drawn from a stream of ``seed`` on its pose, while ``episode.actions`` holds the expert's clean actions; the
    expert's own commanded pose is left alone, so its next action corrects the perturbation. Zero noise is no noise.
    """
    env.reset_to_seed(seed)
    expert = make_expert(env, expert_variation)
    if action_noise is not None and not action_noise.active:
        action_noise = None
    noise_rng = None if action_noise is None else action_noise.generator(seed)
    episode = Episode(env.task_name, env.robot_key, env.variation_index, seed, env.variation.description)
    for _ in range(env.horizon):
        if record_frames and (frame_steps is None or episode.length in frame_steps):
            episode.frames.append(env.render_agentview())
        if record_frame_states:
            episode.frame_states.append(env.frame_state())
        episode.states.append(env.robot_state())
        action = expert.act()
        episode.actions.append(action)
        env.step(action if action_noise is None else action_noise.perturb(action, noise_rng))
        episode.length += 1
        episode.successes.append(env.check_success())
        episode.success = episode.successes[-1]
        if on_step is not None:
            on_step(episode)
        if episode.success:
            break
    if record_frames and record_final_frame and (frame_steps is None or episode.length in frame_steps):
        episode.frames.append(env.render_agentview())
    if record_frame_states and record_final_frame:
        episode.frame_states.append(env.frame_state())
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
    """Concatenate the episodes' frames into one H.264 mp4 (written whole or not at all)."""
    import imageio.v3 as iio

    from mosaic_data.recording_files import file_written_whole

    frames = [frame for episode in episodes for frame in episode.frames]
    if not frames:
        raise ValueError("no frames were recorded")
    with file_written_whole(path) as temporary:
        iio.imwrite(temporary, np.stack(frames), plugin="pyav", fps=fps, codec="libx264")


def write_rerun(path: Path, episodes: list[Episode], fps: int = 20) -> None:
    """Save a rerun recording: camera (JPEG), state and action curves, success.

    Timelines: ``time`` plays all episodes one after the other in real time (``fps``), ``frame`` counts their
    steps, ``episode_step`` restarts in each episode and ``episode`` jumps between them. Each episode goes in
    as a few columns (``send_columns``), not one message per value.
    """
    import rerun as rr
    import rerun.blueprint as rrb

    from mosaic_data.recording_files import StepTimelines, rerun_file, send_jpegs

    blueprint = rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial2DView(origin="/camera", name="agentview"),
                rrb.TextDocumentView(origin="/episode", name="episode"),
                row_shares=[4, 1],
            ),
            rrb.Vertical(
                rrb.TimeSeriesView(origin="/action", name="action (target pose, gripper)"),
                rrb.TimeSeriesView(origin="/state", name="state"),
                rrb.TimeSeriesView(origin="/success", name="success"),
            ),
        ),
        rrb.TimePanel(timeline="time"),
        collapse_panels=True,
    )
    state_names = ["x", "y", "z", "gripper_opening"]
    with rerun_file(path, "mosaic_experts", blueprint) as recording:
        for name in ACTION_NAMES:
            recording.log(f"/action/{name}", rr.SeriesLines(names=name), static=True)
        for name in state_names:
            recording.log(f"/state/{name}", rr.SeriesLines(names=name), static=True)
        recording.log("/success", rr.SeriesLines(names="success"), static=True)
        timelines = StepTimelines(fps, counter="frame", step="episode_step")
        first = 0
        for index, episode in enumerate(episodes):
            times = timelines.columns(index, first, episode.length)
            timelines.set(recording, index, first, 0)
            recording.log("/episode", rr.TextDocument(
                f"{episode.task} / {episode.robot} / variation {episode.variation}: {episode.description} "
                f"(seed {episode.seed}, {'success' if episode.success else 'failure'} in {episode.length} steps)"
            ))
            if episode.frames:
                send_jpegs(recording, "/camera", episode.frames[: episode.length], times)
            actions = np.asarray(episode.actions[: episode.length], dtype=np.float64)
            for column, name in enumerate(ACTION_NAMES):
                recording.send_columns(f"/action/{name}", indexes=times, columns=rr.Scalars.columns(scalars=actions[:, column]))
            states = np.asarray(episode.states[: episode.length], dtype=np.float64)
            for column, name in zip([0, 1, 2, -1], state_names):
                recording.send_columns(f"/state/{name}", indexes=times, columns=rr.Scalars.columns(scalars=states[:, column]))
            success = np.zeros(episode.length)
            success[-1:] = float(episode.success)
            recording.send_columns("/success", indexes=times, columns=rr.Scalars.columns(scalars=success))
            first += episode.length
