"""Where does a policy's episode part from the expert's? One ``mosaic-eval`` episode, step by step, beside the
Panda's scripted expert on the same instance.

    python -m pipelines.bench.rollout_trace --policy.path CHECKPOINT --task door --variation 3 --episodes 0,2 \
        [--every 3] [--seed 1000000000] [--policy.n_action_steps=N ...] [--output trace.csv]

``mosaic-eval`` says which episodes failed and where the hand ended (results.json); this replays them. Episode ``e``
of ``--variation`` is the one ``mosaic-eval --seed S`` runs (the same agent instance, the same fresh demonstration,
torch re-seeded alike, through the evaluation's own worker), so its outcome matches that episode's row in
results.json. The expert then acts on the same instance, without a demonstration. Each printed row shows, at one
control step, both hands (the grip site) and the targets they were sent (world frame, m), the expert's phase and
how far apart the hands are: where a policy stalls, turns back or heads elsewhere shows as the step where the
distance grows and what the expert was doing there. ``--output`` writes every step of both to a CSV file.
``--policy.NAME=VALUE`` rolls the same weights out another way, as in ``mosaic-eval``.
"""

from __future__ import annotations

import argparse
import csv
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mosaic_data.cli_args import OneLineErrorParser, non_negative_int, parse_int_list, positive_int
from mosaic_data.constants import EVAL_BASE_SEED, MAX_EPISODES_PER_VARIATION
from pipelines.evaluation.options import EvaluationError, add_policy_option_arguments, policy_options

APART_M = 0.05
"""The hands count as parted once they stand farther apart than this (the first such step is named)."""


@dataclass
class Track:
    """One agent's episode: per control step, the hand it acted from, the target it sent, the gripper command."""

    hands: list[np.ndarray] = field(default_factory=list)
    targets: list[np.ndarray] = field(default_factory=list)
    grippers: list[float] = field(default_factory=list)
    phases: list[str | None] = field(default_factory=list)
    success: bool = False

    def observe(self, step: int, env, agent_step) -> None:
        self.hands.append(np.array(env.task_env.robot_state()[:3]))
        self.targets.append(np.array(agent_step.action[:3]))
        self.grippers.append(float(agent_step.action[-1]))
        self.phases.append(agent_step.phase)

    def __len__(self) -> int:
        return len(self.hands)


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineErrorParser(prog="python -m pipelines.bench.rollout_trace", description=__doc__.splitlines()[0])
    parser.add_argument("--policy.path", dest="policy_path", required=True, metavar="DIR", help="a lerobot-train checkpoint")
    add_policy_option_arguments(parser)
    parser.add_argument("--task", required=True, help="task name (see `mosaic-data tasks`)")
    parser.add_argument("--variation", type=non_negative_int, required=True, help="the variation demonstrated")
    parser.add_argument("--episodes", type=parse_int_list, default=[0], help="episode indices, as mosaic-eval numbers them (default 0)")
    parser.add_argument("--seed", type=non_negative_int, default=EVAL_BASE_SEED, help=f"mosaic-eval's --seed (default {EVAL_BASE_SEED})")
    parser.add_argument("--every", type=positive_int, default=3, help="print every N-th step (default 3; the CSV has all)")
    parser.add_argument("--max-steps", type=positive_int, default=None, metavar="N", help="cap each episode at N steps")
    parser.add_argument("--output", type=Path, default=None, metavar="TRACE.csv", help="every step of both agents, as CSV")
    return parser


def trace_episodes(args: argparse.Namespace) -> list[tuple[int, object, Track, Track]]:
    """(episode, the policy's EpisodeResult, the policy's track, the expert's track) per episode."""
    from mosaic_data.tasks import select_variations
    from pipelines.evaluation.agents import AgentSpec, policy_agent_spec
    from pipelines.evaluation.demo_sources import DemoSourceSpec
    from pipelines.evaluation.rollouts import EpisodeSpec, RolloutWorker
    from pipelines.evaluation.seeds import episode_seed, episode_seeds

    if args.task == "all":
        raise EvaluationError("--task takes one task: the trace replays episodes of one variation")
    try:
        select_variations(args.task, [args.variation], variations_option="--variation")
    except ValueError as error:
        raise EvaluationError(str(error)) from None
    if not all(0 <= episode < MAX_EPISODES_PER_VARIATION for episode in args.episodes):
        raise EvaluationError(f"--episodes takes indices in 0..{MAX_EPISODES_PER_VARIATION - 1}, got {args.episodes}")
    policy, _ = policy_agent_spec(args.policy_path, policy_options(args))
    expert = AgentSpec("expert", "expert", image_hw=policy.image_hw)
    worker = RolloutWorker([policy, expert], DemoSourceSpec(), max_steps=args.max_steps)
    traced = []
    try:
        for episode in args.episodes:
            seeds = episode_seeds(episode_seed(args.seed, episode), args.variation)
            policy_track, expert_track = Track(), Track()
            policy_result = worker.run(
                EpisodeSpec(0, args.task, args.variation, episode, seeds.agent, seeds.demo), on_step=policy_track.observe
            )
            expert_result = worker.run(
                EpisodeSpec(1, args.task, args.variation, episode, seeds.agent, seeds.demo), on_step=expert_track.observe
            )
            policy_track.success, expert_track.success = policy_result.success, expert_result.success
            traced.append((episode, policy_result, policy_track, expert_track))
    finally:
        worker.close()
    return traced


def parting_step(policy: Track, expert: Track) -> int | None:
    """The first step at which the two hands stand more than APART_M apart (None: never, while both act)."""
    for step in range(min(len(policy), len(expert))):
        if np.linalg.norm(policy.hands[step] - expert.hands[step]) > APART_M:
            return step
    return None


def _xyz(point: np.ndarray | None) -> str:
    return "" if point is None else " ".join(f"{value:6.3f}" for value in point)


def _outcome(track: Track) -> str:
    return f"{'success' if track.success else 'failure'} in {len(track)} steps"


def _at(values: list, step: int):
    """The value at ``step``, or None once that agent's episode has ended."""
    return values[step] if step < len(values) else None


def episode_table(episode: int, result, policy: Track, expert: Track, every: int) -> str:
    parted = parting_step(policy, expert)
    lines = [
        f"{result.task}, variation {result.variation} ({result.description}), episode {episode}: agent instance "
        f"{result.seed}, demonstration {result.demo_seed}",
        f"policy: {_outcome(policy)} (achieved variation: {result.achieved_variation}); expert: {_outcome(expert)}; "
        f"the hands part by more than {APART_M * 100:.0f} cm "
        + (f"at step {parted}" if parted is not None else "at no step where both act"),
        f"{'step':>4} | {'expert phase':<12} | {'expert hand (m)':<20} | {'expert target':<20} | "
        f"{'policy hand (m)':<20} | {'policy target':<20} | grip | apart (cm)",
    ]
    for step in range(0, max(len(policy), len(expert)), every):
        expert_hand, policy_hand = _at(expert.hands, step), _at(policy.hands, step)
        gripper = _at(policy.grippers, step)
        apart = "" if expert_hand is None or policy_hand is None else f"{np.linalg.norm(policy_hand - expert_hand) * 100:6.1f}"
        lines.append(
            f"{step:>4} | {_at(expert.phases, step) or '':<12} | {_xyz(expert_hand):<20} | "
            f"{_xyz(_at(expert.targets, step)):<20} | {_xyz(policy_hand):<20} | {_xyz(_at(policy.targets, step)):<20} | "
            f"{'' if gripper is None else f'{gripper:4.1f}':>4} | {apart}"
        )
    return "\n".join(lines)


def write_csv(path: Path, traced: list[tuple[int, object, Track, Track]]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["episode", "agent", "step", "phase", "hand_x", "hand_y", "hand_z", "target_x", "target_y",
                         "target_z", "gripper"])
        for episode, _, policy, expert in traced:
            for name, track in (("policy", policy), ("expert", expert)):
                for step in range(len(track)):
                    writer.writerow([episode, name, step, track.phases[step] or "",
                                     *np.round(track.hands[step], 5), *np.round(track.targets[step], 5),
                                     round(track.grippers[step], 4)])


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        traced = trace_episodes(args)
    except EvaluationError as error:
        print(f"rollout_trace: {error}", file=sys.stderr)
        return 2
    print("\n\n".join(episode_table(episode, *rest, args.every) for episode, *rest in traced))
    if args.output is not None:
        write_csv(args.output, traced)
        print(f"\nevery step of both agents: {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
