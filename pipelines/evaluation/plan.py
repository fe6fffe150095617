"""What an evaluation runs: its agents, its episodes (with their seeds) and its demo source, checked up front.

Every bad input is found here, before any worker starts: unknown task, variation out of range, a checkpoint
of a policy type LeRobot does not know or whose inputs the environments do not provide, a demo dataset that
lacks a variation or has another image size.

Checkpoints of one policy type form one agent (e.g. a recipe trained with several seeds: mean +- std over
them), named by the type: MOSAIC checkpoints are the row "mosaic", ACT ones "act".
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from typing import Any

from mosaic_data.constants import IMAGE_HEIGHT, IMAGE_WIDTH, MAX_EPISODES_PER_VARIATION, N_DEMO_FRAMES

from .agents import AgentSpec, EvaluationError, policy_agent_spec
from .demo_sources import DatasetDemoSource, DemoSourceSpec
from .options import check_arguments, policy_options
from .rollouts import EpisodeSpec
from .seeds import SEED_RULE, episode_seed, episode_seeds

DATASET_WHERE_HINT = "under HF_LEROBOT_HOME (set that variable to the folder that holds the datasets)"
"""How mosaic-eval says where repo ids are looked up: it has no --output-dir flag, LeRobot's home decides."""


@dataclass
class EvaluationPlan:
    tasks: dict[str, list[int]]
    agents: list[AgentSpec]
    groups: dict[str, dict[int, str]]
    demo_source: DemoSourceSpec
    episodes_per_variation: int
    seed: int
    episodes: list[EpisodeSpec] = field(default_factory=list)
    n_demo_frames: int = N_DEMO_FRAMES
    max_steps: int | None = None
    warnings: list[str] = field(default_factory=list)
    """Inputs that are valid but have no effect, for the command to say (one line each)."""

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> EvaluationPlan:
        tasks = check_arguments(args)
        if not 1 <= args.episodes_per_variation <= MAX_EPISODES_PER_VARIATION:
            raise EvaluationError(
                f"--episodes-per-variation must be in 1..{MAX_EPISODES_PER_VARIATION}, got {args.episodes_per_variation}"
            )
        if args.max_steps is not None and args.max_steps < 1:
            raise EvaluationError(f"--max-steps must be >= 1, got {args.max_steps}")
        if args.workers is not None and args.workers < 1:
            raise EvaluationError(f"--workers must be >= 1, got {args.workers}")
        record = args.rerun is not None
        if record and args.rerun.suffix != ".rrd":
            raise EvaluationError(f"--rerun must name an .rrd file, got {str(args.rerun)!r}")

        agents: list[AgentSpec] = []
        groups: dict[str, dict[int, str]] = {}
        n_demo_frames = N_DEMO_FRAMES
        options = policy_options(args)
        if options and not args.policy_paths:
            raise EvaluationError(
                f"--policy.{next(iter(options))} sets an option of a checkpoint: pass --policy.path=<checkpoint> with it"
            )
        for path in args.policy_paths:
            spec, config = policy_agent_spec(path, options, record)
            n_demo_frames = config.get("n_demo_frames", n_demo_frames) if spec.takes_demo else n_demo_frames
            groups.setdefault(config["type"], {})[len(agents)] = str(path)
            agents.append(spec)
        default_hw = args.image_size or (agents[0].image_hw if agents else (IMAGE_HEIGHT, IMAGE_WIDTH))
        for baseline in dict.fromkeys(args.baseline):
            groups[baseline] = {len(agents): baseline}
            agents.append(AgentSpec(baseline, baseline, None, default_hw, record))

        demo_source = DemoSourceSpec()
        warnings = []
        if args.demo_dataset is not None and not any(agent.needs_demo for agent in agents) and not record:
            warnings.append(_unused_demo_dataset(args.demo_dataset, agents))
        elif args.demo_dataset is not None:
            from mosaic_data.collection.schema import resolve_dataset

            try:
                root = resolve_dataset(args.demo_dataset, where_hint=DATASET_WHERE_HINT)
            except ValueError as error:
                raise EvaluationError(str(error)) from None
            source = None
            for image_hw in {agent.image_hw for agent in agents if agent.needs_demo or record}:
                source = DatasetDemoSource(root, image_hw)
                for task, variations in tasks.items():
                    source.check_covers(task, variations)
            if source is not None:
                source.check_videos(tasks)
            demo_source = DemoSourceSpec(dataset=str(root))

        if not any(agent.needs_demo for agent in agents):
            n_demo_frames = 0  # the recording shows no "frames the policy conditions on" panels
        plan = cls(
            tasks, agents, groups, demo_source, args.episodes_per_variation, args.seed, n_demo_frames=n_demo_frames,
            max_steps=args.max_steps, warnings=warnings,
        )
        recorded_agents = {min(members) for members in groups.values()}
        for agent_index in range(len(agents)):
            for task, variations in tasks.items():
                for variation in variations:
                    for episode in range(args.episodes_per_variation):
                        seeds = episode_seeds(episode_seed(args.seed, episode), variation)
                        plan.episodes.append(EpisodeSpec(
                            agent_index, task, variation, episode, seeds.agent, seeds.demo,
                            record=record and agent_index in recorded_agents and episode < args.rerun_episodes,
                        ))
        return plan

    def settings(self) -> dict[str, Any]:
        return {
            "tasks": self.tasks,
            "agents": [agent.__dict__ | {"image_hw": list(agent.image_hw)} for agent in self.agents],
            "episodes_per_variation": self.episodes_per_variation,
            "seed": self.seed,
            "seed_rule": SEED_RULE,
            "demo_source": self.demo_source.dataset or f"fresh {self.demo_source.robot} expert demonstrations",
            "agent_robot": "panda",
            "max_steps": self.max_steps or "task horizon",
        }


def _unused_demo_dataset(dataset: str, agents: list[AgentSpec]) -> str:
    """Why ``--demo-dataset`` is neither read nor checked: no agent conditions on a demonstration and no recording
    shows one. Said, so that an evaluation of the expert alone does not look like it used (or vouched for) it."""
    names = ", ".join(dict.fromkeys("the expert baseline" if agent.kind == "expert" else agent.label for agent in agents))
    return (
        f"--demo-dataset {dataset} is unused and was not checked: no evaluated agent takes a demonstration ({names}; "
        "the expert reads its goal from the simulator)"
    )
