"""Does a trained policy read the demonstration? Its targets on recorded agent frames, shown the right and a wrong one.

    python -m pipelines.bench.demo_dependence --policy.path CHECKPOINT --data-dir DIR --task door \
        --variations 0,1 [--episodes 2] [--demos 3] [--every 2]

For each of the two variations A and B: the first ``--episodes`` Panda episodes of A in DIR/mosaic/<task>_panda,
every ``--every``-th frame, are given to the policy with each of the first ``--demos`` Sawyer demonstrations of A
(the right one) and of B (a wrong one) from DIR/mosaic/<task>_sawyer. Per tenth of the episode it prints, in
metres (the checkpoint's own postprocessor), the mean distance from the recorded expert target to the policy's
first target under the right demonstrations and under the wrong ones, and between the two. A policy that reads
the demonstration is closer to the expert with the right one wherever the two variations' experts differ; where
the two columns are equal the frame alone decides what the policy does. Rollouts say whether the policy succeeds;
this says at which part of an episode the demonstration changes its action, on frames from the data (no
simulator).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from mosaic_data.constants import ACTION_KEY, CAMERA_KEY, STATE_KEY
from mosaic_data.tasks.spec import TASK_SPECS

PARTS = 10
"""The episode is cut into this many parts of equal length (by frame index)."""
VARIATION_KEY = "variation"
"""The per-frame variation index every collected dataset holds (mosaic_data.collection.schema)."""


def load_policy(path: Path):
    """mosaic-eval's own agent of a lerobot-train checkpoint: its policy, preprocessor and postprocessor."""
    from pipelines.evaluation.agents import AgentSpec, PolicyAgent

    return PolicyAgent.from_spec(AgentSpec(kind="policy", label="policy", path=str(path)))


def episodes_of(dataset, variation: int, count: int) -> list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
    """(frames (T, 3, H, W) float, robot states (T, S), actions (T, A)) of the first ``count`` episodes of
    ``variation`` (the datasets' per-frame ``variation`` feature)."""
    found = []
    for episode in range(dataset.meta.total_episodes):
        start, end = dataset.meta.episodes[episode]["dataset_from_index"], dataset.meta.episodes[episode]["dataset_to_index"]
        if int(dataset.hf_dataset[start][VARIATION_KEY]) != variation:
            continue
        items = [dataset[i] for i in range(start, end)]
        found.append(tuple(torch.stack([item[key] for item in items]) for key in (CAMERA_KEY, STATE_KEY, ACTION_KEY)))
        if len(found) == count:
            break
    if not found:
        raise SystemExit(f"no episode of variation {variation} in {dataset.root}: collect it first.")
    return found


@torch.no_grad()
def first_targets(policy_agent, demo: torch.Tensor, frames: torch.Tensor, states: torch.Tensor) -> np.ndarray:
    """(T, 3) unnormalised position targets the policy gives first for each frame and robot state, conditioned on
    ``demo``; frame and state go through the checkpoint's own preprocessor, as in an evaluation."""
    policy = policy_agent.policy
    policy.reset()
    policy.set_demo(demo)
    chunks = []
    for frame, state in zip(frames, states, strict=True):
        batch = policy_agent.preprocessor({CAMERA_KEY: frame[None], STATE_KEY: state[None], "task": [""]})
        chunks.append(policy.predict_action_chunk(batch)[:, 0])
    return policy_agent.postprocessor(torch.cat(chunks))[:, :3].numpy()


def dependence_table(policy_agent, agent, demos_right, demos_wrong, every: int) -> np.ndarray:
    """(PARTS, 3): per tenth of the episodes, mean distance expert-right, expert-wrong, right-wrong (metres)."""
    sums, counts = np.zeros((PARTS, 3)), np.zeros(PARTS)
    for frames, states, actions in agent:
        index = np.arange(0, len(frames), every)
        expert = actions[index, :3].numpy()
        right = np.mean([first_targets(policy_agent, d, frames[index], states[index]) for d in demos_right], axis=0)
        wrong = np.mean([first_targets(policy_agent, d, frames[index], states[index]) for d in demos_wrong], axis=0)
        part = np.minimum(index * PARTS // len(frames), PARTS - 1)
        distances = np.stack(
            [np.linalg.norm(expert - right, axis=1), np.linalg.norm(expert - wrong, axis=1), np.linalg.norm(right - wrong, axis=1)],
            axis=1,
        )
        np.add.at(sums, part, distances)
        np.add.at(counts, part, 1)
    return sums / np.maximum(counts, 1)[:, None]


def bench_parser(doc: str, data_dir_help: str) -> argparse.ArgumentParser:
    """The arguments the demonstration benches share: the checkpoint, the collected data, the task."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--policy.path", dest="policy_path", type=Path, required=True)
    parser.add_argument("--data-dir", type=Path, required=True, help=data_dir_help)
    parser.add_argument("--task", default="door", choices=sorted(TASK_SPECS))
    return parser


def demonstrated_variations(bench: str, task: str, text: str) -> list[int]:
    """``--variations`` of the benches that compare demonstrations: comma-separated indices (empty: all of the
    task's), two or more, each in range; otherwise one line naming the range."""
    count = len(TASK_SPECS[task].variations)
    variations = [int(v) for v in text.split(",") if v] or list(range(count))
    if len(variations) < 2 or not all(0 <= v < count for v in variations):
        raise SystemExit(f"{bench}: --variations takes two or more of {task}'s 0..{count - 1}.")
    return variations


def open_dataset(bench: str, data_dir: Path, task: str, robot: str):
    """The LeRobot dataset DATA_DIR/mosaic/<task>_<robot>, or one line naming the command that collects it."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    root = data_dir / "mosaic" / f"{task}_{robot}"
    if not (root / "meta" / "info.json").is_file():
        raise SystemExit(f"{bench}: no dataset at {root}: mosaic-data collect --task {task} --output-dir {data_dir}")
    return LeRobotDataset(f"mosaic/{task}_{robot}", root=root)


def main(argv: list[str] | None = None) -> None:
    parser = bench_parser(__doc__, "holds mosaic/<task>_panda and mosaic/<task>_sawyer")
    parser.add_argument("--variations", default="0,1", help="two variation indices A,B")
    parser.add_argument("--episodes", type=int, default=2, help="agent episodes per variation")
    parser.add_argument("--demos", type=int, default=3, help="demonstrations per variation")
    parser.add_argument("--every", type=int, default=2, help="use every k-th frame")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    variations = TASK_SPECS[args.task].variations
    pair = [int(v) for v in args.variations.split(",")]
    if len(pair) != 2 or not all(0 <= v < len(variations) for v in pair):
        raise SystemExit(f"demo_dependence: --variations takes two indices of {args.task}'s 0..{len(variations) - 1}.")
    datasets = {robot: open_dataset("demo_dependence", args.data_dir, args.task, robot) for robot in ("panda", "sawyer")}
    policy_agent = load_policy(args.policy_path)
    demos = {v: [episode[0] for episode in episodes_of(datasets["sawyer"], v, args.demos)] for v in pair}
    for shown, other in (pair, pair[::-1]):
        agent = episodes_of(datasets["panda"], shown, args.episodes)
        table = dependence_table(policy_agent, agent, demos[shown], demos[other], args.every)
        print(f"\nagent frames of {shown} ({variations[shown].description}); wrong demonstration: {other} "
              f"({variations[other].description}); {len(agent)} episodes, {args.demos} demonstrations each")
        print("| part of the episode | expert - policy, right demo (cm) | expert - policy, wrong demo (cm) | right - wrong (cm) |")
        print("|---|---|---|---|")
        for part, (right, wrong, between) in enumerate(table):
            print(f"| {part * 10}-{part * 10 + 10}% | {right * 100:.1f} | {wrong * 100:.1f} | {between * 100:.1f} |")


if __name__ == "__main__":
    main()
