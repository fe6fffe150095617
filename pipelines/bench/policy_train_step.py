"""Benchmark: MOSAIC training step (paper settings) and attention cost against full spatio-temporal attention.

    python -m pipelines.bench.policy_train_step [--batch-size 30] [--steps 3] [--threads N]

Prints: seconds per training step (forward + backward + Adam + EMA update; batch 30, 4 demo + 7 observation
frames at 100x180, 2 attention layers, contrastive before and after attention), peak resident memory, and the
time of the attention stack alone on the same features in the same run: the MOSAIC pattern through its fused
attention kernel (training's path), the MOSAIC pattern through the explicit computation that also returns the
attention maps (`return_weights=True`, what recording an episode uses), and the full spatio-temporal pattern
(T-OSIL style: observation frames attend causally to all observation frames besides the demo), with the ratios
MOSAIC/full and fused/explicit. The three are timed in interleaved rounds so that load from other processes
falls on all of them alike.
"""

import argparse
import resource
import statistics
import time

import torch

from lerobot.configs import FeatureType, PolicyFeature

from mosaic_data.constants import ACTION_DIM, ACTION_KEY, CAMERA_KEY, DEMO_FRAMES_KEY, STATE_DIM, STATE_KEY


def paper_config(height: int, width: int, **overrides):
    from mosaic_policy import MosaicConfig

    return MosaicConfig(
        device="cpu",
        input_features={
            CAMERA_KEY: PolicyFeature(FeatureType.VISUAL, (3, height, width)),
            STATE_KEY: PolicyFeature(FeatureType.STATE, (STATE_DIM,)),
        },
        output_features={ACTION_KEY: PolicyFeature(FeatureType.ACTION, (ACTION_DIM,))},
        push_to_hub=False,
        **overrides,
    )


def synthetic_batch(config, batch_size: int, height: int, width: int) -> dict:
    t, d = config.train_obs_frames, config.n_demo_frames
    n_actions = len(config.action_delta_indices)  # the window's 20 Hz actions, as lerobot-train loads them
    return {
        CAMERA_KEY: torch.rand(batch_size, t, 3, height, width),
        STATE_KEY: torch.randn(batch_size, t, STATE_DIM),
        ACTION_KEY: torch.rand(batch_size, n_actions, ACTION_DIM) * 2 - 1,
        f"{ACTION_KEY}_is_pad": torch.zeros(batch_size, n_actions, dtype=torch.bool),
        DEMO_FRAMES_KEY: torch.rand(batch_size, d, 3, height, width),
        "task": [f"variation {i % 4}" for i in range(batch_size)],
    }


def peak_rss_gib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20


def time_train_steps(batch_size: int, steps: int, height: int, width: int) -> list[float]:
    from mosaic_policy.mosaic.modeling_mosaic import MosaicPolicy

    config = paper_config(height, width)
    policy = MosaicPolicy(config).train()
    optimizer = torch.optim.Adam(policy.get_optim_params(), lr=config.optimizer_lr)
    batch = synthetic_batch(config, batch_size, height, width)
    times = []
    for _ in range(steps + 1):  # the first step warms up oneDNN
        start = time.perf_counter()
        loss, _ = policy.forward(batch)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        policy.update()
        times.append(time.perf_counter() - start)
    return times[1:]


def time_attention(batch_size: int, feature_shape: tuple[int, int, int], repeats: int) -> dict[str, float]:
    """Median seconds of forward + backward through the 2-layer attention stack on fixed features, per variant:
    "fused" (MOSAIC pattern, no weights), "explicit" (MOSAIC pattern with weights), "full" (T-OSIL pattern)."""
    from mosaic_policy.common.attention import NonLocalAttentionStack

    c, h, w = feature_shape
    torch.manual_seed(0)
    mosaic = NonLocalAttentionStack(c, 2, 4, 16.0, 0.0, "mosaic")
    full = NonLocalAttentionStack(c, 2, 4, 16.0, 0.0, "full")
    full.load_state_dict(mosaic.state_dict())
    demo = torch.randn(batch_size, c, 4, h, w, requires_grad=True)
    obs = torch.randn(batch_size, c, 7, h, w, requires_grad=True)
    variants = {"fused": (mosaic, False), "explicit": (mosaic, True), "full": (full, False)}
    # One thread: the thread's CPU time is the work itself, robust to other processes sharing the cores.
    clock = time.thread_time if torch.get_num_threads() == 1 else time.perf_counter
    times = {name: [] for name in variants}
    for round_ in range(repeats + 1):  # the first round warms up
        for name, (stack, return_weights) in variants.items():
            start = clock()
            demo_out, obs_out, _ = stack(demo, obs, return_weights)
            (demo_out.sum() + obs_out.sum()).backward()
            if round_:
                times[name].append(clock() - start)
            demo.grad = obs.grad = None
            stack.zero_grad(set_to_none=True)
    return {name: statistics.median(t) for name, t in times.items()}


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--batch-size", type=int, default=30)
    parser.add_argument("--steps", type=int, default=3, help="timed steps after one warm-up step")
    parser.add_argument("--height", type=int, default=100)
    parser.add_argument("--width", type=int, default=180)
    parser.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's choice)")
    parser.add_argument("--attention-repeats", type=int, default=3, help="timed rounds of the attention comparison")
    parser.add_argument("--skip-train", action="store_true", help="only the attention comparison")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    device = "cuda" if torch.cuda.is_available() else "cpu"
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, device for this run: cpu (cuda available: {device == 'cuda'})")

    from mosaic_policy.common.resnet_trunk import ResNetTrunk

    feature_shape = ResNetTrunk().feature_shape(args.height, args.width)
    print(f"features per frame at {args.height}x{args.width}: {feature_shape}")

    times = time_attention(args.batch_size, feature_shape, repeats=args.attention_repeats)
    fused, explicit, full = times["fused"], times["explicit"], times["full"]
    tokens = feature_shape[1] * feature_shape[2]
    # query-key pairs per sample and layer: demo self-attention, then the observation queries' keys
    demo_pairs = (4 * tokens) ** 2
    pairs_mosaic = demo_pairs + 7 * tokens * (tokens + 4 * tokens)
    pairs_full = demo_pairs + 7 * tokens * (4 * tokens + 7 * tokens)  # what the masked kernel computes
    pairs_causal = demo_pairs + sum(tokens * (4 * tokens + (t + 1) * tokens) for t in range(7))  # what the mask keeps
    clock = "thread CPU time" if torch.get_num_threads() == 1 else "wall time"
    print(
        f"attention stack fwd+bwd ({clock}, median of {args.attention_repeats}), batch {args.batch_size}, "
        f"4 demo + 7 observation frames:\n"
        f"  mosaic fused {fused * 1e3:.0f} ms, mosaic explicit (with weights) {explicit * 1e3:.0f} ms, "
        f"full (causal) {full * 1e3:.0f} ms\n"
        f"  ratios: mosaic fused/full {fused / full:.2f}, mosaic explicit/full {explicit / full:.2f}, "
        f"fused/explicit {fused / explicit:.2f}\n"
        f"  query-key pairs mosaic/full {pairs_mosaic / pairs_full:.2f} as computed "
        f"({pairs_mosaic / pairs_causal:.2f} of those the causal mask keeps)"
    )

    if not args.skip_train:
        times = time_train_steps(args.batch_size, args.steps, args.height, args.width)
        print(
            f"train step (batch {args.batch_size}, 4+7 frames, {args.height}x{args.width}, contrastive both): "
            f"median {statistics.median(times):.2f} s, min {min(times):.2f} s over {len(times)} steps "
            f"-> {args.batch_size / statistics.median(times):.1f} samples/s"
        )
    print(f"peak resident memory: {peak_rss_gib():.2f} GiB")


if __name__ == "__main__":
    main()
