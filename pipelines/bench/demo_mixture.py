"""Where does a trained policy keep the choice between variations: in the demonstration, or in its mixture head?

    python -m pipelines.bench.demo_mixture --policy.path CHECKPOINT --data-dir DIR --task press_button \
        [--shown 0] [--variations 0,1,2,3,4,5] [--episodes 2] [--every 3]

The action head models every target dimension as a mixture of ``n_mixtures`` logistics, and the policy acts with
the mean of the most likely component. A head can make the variations' different targets likely in two ways:
read the demonstration and move one component to the shown variation's target, or give each variation's target a
component of its own, weighted the same whatever the demonstration. The second fits the recorded actions almost as
well and acts with the heaviest component every time: the same variation whatever it is shown.

On the first ``--episodes`` Panda episodes of variation ``--shown`` (DIR/mosaic/<task>_panda), every ``--every``-th
frame is given to the policy with the first Sawyer demonstration of each of ``--variations`` (DIR/mosaic/<task>_sawyer).
Per tenth of the episode it prints, over the position dimensions (x, y, z) of every chunk step: the heaviest
component's weight (1 for one component: nothing left to the mixture), how far the demonstrations move the
components' weights (total variation from their mean over the demonstrations; 0: the weights ignore the
demonstration), and how far apart the acted-on targets of the chunk's last step are between demonstrations (cm,
the checkpoint's own postprocessor). A heaviest weight well under 1, weights the demonstrations barely move and
targets a few centimetres apart are the second way; rollouts then do one or two variations whatever they are shown.
"""

from __future__ import annotations

import numpy as np
import torch

from mosaic_data.constants import CAMERA_KEY, STATE_KEY
from mosaic_data.tasks.spec import TASK_SPECS

from .demo_dependence import PARTS, bench_parser, demonstrated_variations, episodes_of, load_policy, open_dataset

POSITION_DIMS = 3
"""x, y, z: the first action dimensions (mosaic_data's action layout)."""


@torch.no_grad()
def demo_contexts(policy, demos: list[torch.Tensor]) -> list:
    """What `set_demo` computes from each demonstration, once per demonstration (the policy keeps its inference
    trunk from the last call)."""
    contexts = []
    for demo in demos:
        policy.reset()
        policy.set_demo(demo)
        contexts.append(policy._context)
    return contexts


@torch.no_grad()
def frame_mixtures(policy_agent, contexts: list, frame: torch.Tensor, state: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
    """For one agent frame and each demonstration's context: the position dimensions' component weights
    (D, chunk, 3, M) and the unnormalised position target of the chunk's last step (D, 3), as the policy acts on them."""
    policy = policy_agent.policy
    batch = policy_agent.preprocessor({CAMERA_KEY: frame[None], STATE_KEY: state[None], "task": [""]})
    image, robot_state = policy.current_inputs(batch)
    chunk, action_dim = policy.config.action_chunk, policy.action_dim
    weights, targets = [], []
    for context in contexts:
        distribution = policy.chunk_distribution(image, robot_state, context)
        probs = torch.softmax(distribution.logit_probs, dim=-1).reshape(1, chunk, action_dim, -1)
        weights.append(probs[0, :, :POSITION_DIMS].numpy())
        last = policy.actions_of(distribution, robot_state)[:, -1]
        targets.append(policy_agent.postprocessor(last)[0, :POSITION_DIMS].numpy())
    return np.stack(weights), np.stack(targets)


def mixture_table(policy_agent, agent_episodes, demos: list[torch.Tensor], every: int) -> np.ndarray:
    """(PARTS, 3): per tenth of the episodes, the heaviest component's mean weight, the mean total variation of the
    weights from their mean over the demonstrations, the mean distance (m) of the last targets from their mean (NaN
    where no frame falls in that tenth)."""
    contexts = demo_contexts(policy_agent.policy, demos)
    sums, counts = np.zeros((PARTS, 3)), np.zeros(PARTS)
    for frames, states, _ in agent_episodes:
        for index in range(0, len(frames), every):
            weights, targets = frame_mixtures(policy_agent, contexts, frames[index], states[index])
            heaviest = weights.max(-1).mean()
            shift = 0.5 * np.abs(weights - weights.mean(0, keepdims=True)).sum(-1).mean()
            spread = np.linalg.norm(targets - targets.mean(0, keepdims=True), axis=1).mean()
            part = min(index * PARTS // len(frames), PARTS - 1)
            sums[part] += (heaviest, shift, spread)
            counts[part] += 1
    with np.errstate(invalid="ignore"):
        return np.where(counts[:, None] > 0, sums / np.maximum(counts, 1)[:, None], np.nan)  # NaN: no frame in that tenth


def main(argv: list[str] | None = None) -> None:
    parser = bench_parser(__doc__, "holds mosaic/<task>_panda and mosaic/<task>_sawyer")
    parser.add_argument("--shown", type=int, default=0, help="variation of the agent episodes")
    parser.add_argument("--variations", default="", help="demonstrated variations, comma-separated (default: all)")
    parser.add_argument("--episodes", type=int, default=2, help="agent episodes")
    parser.add_argument("--every", type=int, default=3, help="use every k-th frame")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    variations = demonstrated_variations("demo_mixture", args.task, args.variations)
    if not 0 <= args.shown < len(TASK_SPECS[args.task].variations):
        raise SystemExit(f"demo_mixture: --shown takes one of {args.task}'s {len(TASK_SPECS[args.task].variations)} variations.")
    datasets = {robot: open_dataset("demo_mixture", args.data_dir, args.task, robot) for robot in ("panda", "sawyer")}
    policy_agent = load_policy(args.policy_path)
    if not hasattr(policy_agent.policy, "chunk_distribution"):
        raise SystemExit(f"demo_mixture: {args.policy_path} holds no mixture head: give a MOSAIC or baseline checkpoint.")
    demos = [episodes_of(datasets["sawyer"], v, 1)[0][0] for v in variations]
    agent = episodes_of(datasets["panda"], args.shown, args.episodes)
    table = mixture_table(policy_agent, agent, demos, args.every)
    print(f"\nagent frames of {args.shown} ({TASK_SPECS[args.task].variations[args.shown].description}), {len(agent)} "
          f"episodes; one demonstration of each of {variations}; {policy_agent.policy.config.n_mixtures} mixture components")
    print("| part of the episode | heaviest component's weight | weights moved by the demonstration (total variation) "
          "| last targets apart between demonstrations (cm) |")
    print("|---|---|---|---|")
    for part, (heaviest, shift, spread) in enumerate(table):
        cells = ["-"] * 3 if np.isnan(heaviest) else [f"{heaviest:.2f}", f"{shift:.3f}", f"{spread * 100:.1f}"]
        print(f"| {part * 10}-{part * 10 + 10}% | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
