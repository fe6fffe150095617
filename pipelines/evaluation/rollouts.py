"""One evaluation episode: a demonstration of the variation, a fresh agent instance, a rollout to the horizon.

Seeds (one rule for both front-ends, :mod:`.seeds`): episode ``e`` of ``variation`` from base seed ``B``
(``--seed``) has the episode seed ``s = B + e``, what ``lerobot-eval --seed B`` resets its environments with;
the agent faces instance ``s + 100000 * variation`` and the demonstrator's expert shows instance
``s + 100000 * variation + 50000`` (``+ 5000`` per retry if its expert fails there), so the demonstration always
shows another instance than the one the agent faces. The demonstration is made by the same source and frame
picking as in ``lerobot-eval --env.type=mosaic`` (:class:`.demo_sources.ExpertDemoSource`,
:func:`.demo_sources.policy_frames`), so ``mosaic-eval --seed B`` and ``lerobot-eval --seed B`` run the same
episodes and give the same numbers (mind their different default seeds: pass the same ``--seed`` to both).
Everything an episode does depends only on its seeds (torch's generator is re-seeded per episode), so results
do not depend on the number of workers or on which worker runs an episode. The default base, 10^9, is far from
the seeds `mosaic-data collect` uses for training data (base 0).

Every episode also records which variation the agent *achieved* (:class:`GoalTracker`), for the confusion matrix.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import torch

from mosaic_data.envs import MosaicGymEnv
from mosaic_data.tasks import get_task_class

from .agents import Agent, AgentSpec, AgentStep, build_agent
from .demo_sources import DemoSourceSpec, build_demo_source, policy_frames
from .env_cache import EnvCache

if TYPE_CHECKING:
    from mosaic_data.tasks.base import MosaicTaskEnv


StepObserver = Callable[[int, MosaicGymEnv, AgentStep], None]
"""Called with (step index, environment, the agent's step) before each action is applied."""


@dataclass(frozen=True)
class EpisodeSpec:
    agent_index: int
    task: str
    variation: int
    episode: int
    seed: int
    demo_seed: int
    record: bool = False


@dataclass
class EpisodeRecording:
    """What the rerun recording shows of one episode (kept only for recorded episodes)."""

    demo_video: np.ndarray  # (N, H, W, 3) uint8, the whole demonstration
    demo_indices: list[int]  # frames of it the policy conditions on
    frames: list[np.ndarray] = field(default_factory=list)  # agent camera, one per action
    actions: list[np.ndarray] = field(default_factory=list)
    attention: list[np.ndarray] = field(default_factory=list)  # per step (layers, h*w + demo tokens), head/query means
    feature_hw: tuple[int, int] | None = None


class GoalTracker:
    """Which variation's goal the agent reached: all variations of a task share the scene, so every variation's
    success test runs after each step (no rendering: microseconds). A goal counts only when it becomes reached
    during the episode, never one that already holds in the start state (a drawer to close starts open, which
    may satisfy another variation's test)."""

    def __init__(self, task_env: MosaicTaskEnv) -> None:
        self.task_env = task_env
        self._held = self._goals()
        self.first_step: dict[int, int] = {}  # variation -> step at which its goal was first reached

    def _goals(self) -> list[bool]:
        return [self.task_env.check_success(variation=j) for j in range(len(self.task_env.variations))]

    def update(self, step: int) -> None:
        for variation, held in enumerate(self._goals()):
            if held and not self._held[variation]:
                self.first_step.setdefault(variation, step)
            self._held[variation] = held

    def achieved(self, own: int, success: bool) -> int | None:
        """Its own variation on success (the episode ends there), else the first other variation whose goal was
        reached (lowest index on a tie), else None."""
        if success:
            return own
        others = sorted((step, variation) for variation, step in self.first_step.items() if variation != own)
        return others[0][1] if others else None


@dataclass
class EpisodeResult:
    agent_index: int
    agent: str
    task: str
    variation: int
    description: str
    episode: int
    seed: int
    demo_seed: int | None
    success: bool
    achieved_variation: int | None  # whose goal the agent reached (see GoalTracker); None: no variation's
    steps: int
    horizon: int
    final_position: list[float]  # the gripper's grip site at the end (m), where the agent left off
    rollout_s: float
    act_s: float
    demo_s: float
    recording: EpisodeRecording | None = None

    def summary(self) -> dict:
        """JSON-ready fields (the recording left out)."""
        return {name: getattr(self, name) for name in self.__dataclass_fields__ if name != "recording"}


class RolloutWorker:
    """Runs episodes for several agents in one process, keeping agents, environments and demo sources."""

    def __init__(
        self, agent_specs: list[AgentSpec], demo_spec: DemoSourceSpec, max_steps: int | None = None
    ) -> None:
        self.agent_specs = agent_specs
        self.demo_spec = demo_spec
        self.max_steps = max_steps
        self._agents: dict[int, Agent] = {}
        self._demo_sources: dict[tuple[int, int], object] = {}
        self._envs = EnvCache()

    def run(self, spec: EpisodeSpec, on_step: StepObserver | None = None) -> EpisodeResult:
        """One episode; ``on_step(step, env, agent_step)`` is called before each action is applied, with the state
        the agent acted on (a step-by-step trace of the episode)."""
        agent = self._agent(spec.agent_index)
        agent_spec = agent.spec
        record = spec.record
        pick = _frame_picker(agent)
        env = self._env(spec.task, spec.variation, agent_spec.image_hw, agent_spec.needs_camera or record)
        torch.manual_seed(spec.seed)
        start = time.perf_counter()
        demo, demo_s = None, 0.0
        if agent_spec.needs_demo or record:  # a recording shows the whole demonstration, so render all of it
            source = self._demo_source(agent_spec.image_hw)
            demo = source.demonstration(spec.task, spec.variation, spec.demo_seed, None if record else pick)
            demo_s = time.perf_counter() - start
        observation, info = env.reset(seed=spec.seed, options={"variation": spec.variation})
        goals = GoalTracker(env.task_env)
        agent.start_episode(env, demo)
        recording = None
        if record:
            recording = EpisodeRecording(demo.frames, pick(demo.length) if pick is not None else [])
        act_s, steps = 0.0, 0
        for _ in range(env.horizon):
            tick = time.perf_counter()
            step = agent.act(observation, env)
            act_s += time.perf_counter() - tick
            if recording is not None:
                recording.frames.append(observation["pixels"]["agentview"])
                recording.actions.append(step.action)
                if step.attention is not None:
                    recording.attention.append(np.stack([layer.mean(axis=(0, 1)) for layer in step.attention]))
            if on_step is not None:
                on_step(steps, env, step)
            observation, _, terminated, truncated, info = env.step(step.action)
            steps += 1
            goals.update(steps)
            if terminated or truncated:
                break
        if recording is not None:
            recording.feature_hw = getattr(agent, "attention_hw", None)
        success = bool(info["is_success"])
        return EpisodeResult(
            agent_index=spec.agent_index,
            agent=agent_spec.label,
            task=spec.task,
            variation=spec.variation,
            description=env.task_description,
            episode=spec.episode,
            seed=spec.seed,
            demo_seed=demo.seed if demo is not None else None,
            success=success,
            achieved_variation=goals.achieved(spec.variation, success),
            steps=steps,
            horizon=env.horizon,
            final_position=[round(float(x), 6) for x in env.task_env.robot_state()[:3]],
            rollout_s=time.perf_counter() - start,
            act_s=act_s,
            demo_s=demo_s,
            recording=recording,
        )

    def _agent(self, index: int) -> Agent:
        if index not in self._agents:
            self._agents[index] = build_agent(self.agent_specs[index])
        return self._agents[index]

    def _demo_source(self, image_hw: tuple[int, int]):
        if image_hw not in self._demo_sources:
            self._demo_sources[image_hw] = build_demo_source(self.demo_spec, image_hw)
        return self._demo_sources[image_hw]

    def _env(self, task: str, variation: int, image_hw: tuple[int, int], camera: bool) -> MosaicGymEnv:
        """The agent's environment: one scene per task (and camera) serves all its variations, each episode's reset
        names its variation; building a scene costs seconds and memory the worker does not get back."""
        horizon = get_task_class(task).horizon_steps
        horizon = min(horizon, self.max_steps) if self.max_steps else horizon
        return self._envs.get(
            (task, image_hw, camera),
            lambda: MosaicGymEnv(
                task, variation, robot="panda", image_height=image_hw[0], image_width=image_hw[1],
                observe_image=camera, horizon=horizon,
            ),
        )

    def close(self) -> None:
        self._envs.close()
        for source in self._demo_sources.values():
            source.close()


def _frame_picker(agent: Agent):
    """The demonstration frames a policy conditions on (first, last, middle-segment centres); None (all frames)
    for an agent that takes no demonstration or a policy that does not say how many frames it uses."""
    return policy_frames(getattr(agent.policy.config, "n_demo_frames", None) if agent.spec.needs_demo else None)
