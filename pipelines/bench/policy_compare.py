"""Benchmark: every policy of the paper's Table I against MOSAIC, measured in one run on this machine.

    python -m pipelines.bench.policy_compare [--batch-size 30] [--steps 2] [--calls 30] [--output compare.json]
    python -m pipelines.bench.policy_compare --batch-size 16 --height 48 --width 88 --vision-backbone conv \\
        --action-chunk 10 --threads 2 --steps 5     # the sizes of mosaic-experiment's cpu preset

For each policy type at its default (single-task) size, 100x180 frames: trainable parameters, seconds per
training step (forward + backward + Adam + the policy's update; batch 30, 4 demo + 7 observation frames) and
the latency of one policy query with a cached demonstration (`predict_action_chunk`, batch 1; `select_action`
runs one query every `action_chunk` control steps), each also as a ratio to MOSAIC's. The machine is shared and
noisy: only ratios from the same run compare. The table also says how many training steps an hour buys at the
measured step time (what a recipe run of each policy costs at those sizes).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import torch

from mosaic_data.constants import CAMERA_KEY, STATE_DIM, STATE_KEY, VISION_BACKBONES, policy_features
from pipelines.bench.policy_train_step import peak_rss_gib, synthetic_batch


def default_config(policy_type: str, height: int, width: int, **overrides):
    from lerobot.configs import PreTrainedConfig

    import mosaic_policy  # noqa: F401  (registers the types)

    return PreTrainedConfig.get_choice_class(policy_type)(
        device="cpu", **policy_features(height, width), push_to_hub=False, **overrides
    )


def trainable_parameters(policy: torch.nn.Module) -> int:
    return sum(p.numel() for p in policy.parameters() if p.requires_grad)


def time_train_steps(policy, batch: dict, steps: int) -> float:
    """Median seconds of a training step, after one warm-up step."""
    optimizer = torch.optim.Adam(policy.get_optim_params(), lr=5e-4)
    policy.train()
    times = []
    for _ in range(steps + 1):
        start = time.perf_counter()
        loss, _ = policy.forward(batch)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        if hasattr(policy, "update"):
            policy.update()
        times.append(time.perf_counter() - start)
    return statistics.median(times[1:])


def time_query(policy, height: int, width: int, calls: int) -> float:
    """Median milliseconds of one query (`predict_action_chunk`) after `set_demo`, batch 1, eval mode."""
    policy.eval()
    policy.reset()
    policy.set_demo(torch.randint(0, 256, (80, height, width, 3), dtype=torch.uint8))
    observation = {CAMERA_KEY: torch.rand(1, 3, height, width), STATE_KEY: torch.randn(1, STATE_DIM)}
    times = []
    with torch.inference_mode():
        for i in range(calls + 5):
            start = time.perf_counter()
            policy.predict_action_chunk(observation)
            if i >= 5:
                times.append((time.perf_counter() - start) * 1e3)
    return statistics.median(times)


def measure(policy_type: str, args: argparse.Namespace) -> dict:
    from mosaic_policy import policy_class

    torch.manual_seed(0)
    overrides = {"vision_backbone": args.vision_backbone}
    if args.action_chunk is not None:
        overrides["action_chunk"] = args.action_chunk
    config = default_config(policy_type, args.height, args.width, **overrides)
    policy = policy_class(policy_type)(config)
    row = {"policy": policy_type, "parameters": trainable_parameters(policy)}
    batch = synthetic_batch(config, args.batch_size, args.height, args.width)
    row["train_step_s"] = None if args.skip_train else time_train_steps(policy, batch, args.steps)
    row["query_ms"] = time_query(policy, args.height, args.width, args.calls)
    return row


def markdown(rows: list[dict], args: argparse.Namespace) -> str:
    from mosaic_policy import POLICY_TYPES

    reference = next(row for row in rows if row["policy"] == "mosaic")
    lines = [
        f"| policy | trainable parameters | train step (batch {args.batch_size}, {args.height}x{args.width}, "
        f"{args.vision_backbone}) | steps per hour | query latency (batch 1) |",
        "|---|---|---|---|---|",
    ]
    for row in rows:
        step = row["train_step_s"]
        step_cell = f"{step:.2f} s ({step / reference['train_step_s']:.2f}x)" if step else "-"
        hour_cell = f"{3600 / step:.0f}" if step else "-"
        lines.append(
            f"| {POLICY_TYPES[row['policy']]} (`{row['policy']}`) "
            f"| {row['parameters'] / 1e6:.2f} M ({row['parameters'] / reference['parameters']:.2f}x) "
            f"| {step_cell} | {hour_cell} | {row['query_ms']:.1f} ms ({row['query_ms'] / reference['query_ms']:.2f}x) |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    from mosaic_policy import POLICY_TYPES

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--policies", nargs="+", default=list(POLICY_TYPES), choices=list(POLICY_TYPES))
    parser.add_argument("--batch-size", type=int, default=30)
    parser.add_argument("--steps", type=int, default=2, help="timed training steps after one warm-up step")
    parser.add_argument("--calls", type=int, default=30, help="timed queries after five warm-up queries")
    parser.add_argument("--height", type=int, default=100)
    parser.add_argument("--width", type=int, default=180)
    parser.add_argument("--vision-backbone", choices=VISION_BACKBONES, default="resnet18",
                        help="every policy's trunk (conv: the cpu preset's)")
    parser.add_argument("--action-chunk", type=int, default=None, help="every policy's action chunk (default: its own)")
    parser.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's choice)")
    parser.add_argument("--skip-train", action="store_true", help="parameters and query latency only")
    parser.add_argument("--output", type=Path, default=None, help="also write the figures as JSON here")
    args = parser.parse_args(argv)
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    policies = ["mosaic"] + [p for p in args.policies if p != "mosaic"]  # the reference first
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, cpu")
    rows = []
    for policy_type in policies:
        rows.append(measure(policy_type, args))
        row = rows[-1]
        step = f"{row['train_step_s']:.2f} s" if row["train_step_s"] else "not timed"
        print(f"{policy_type}: {row['parameters']} parameters, step {step}, query {row['query_ms']:.1f} ms", flush=True)
    print(markdown(rows, args))
    print(f"peak resident memory: {peak_rss_gib():.2f} GiB")
    if args.output is not None:
        args.output.write_text(json.dumps({"settings": vars(args) | {"output": str(args.output)}, "rows": rows}, indent=2))


if __name__ == "__main__":
    main()
