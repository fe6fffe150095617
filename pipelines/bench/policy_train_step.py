"""Benchmark: MOSAIC training step (paper settings) and attention cost against full spatio-temporal attention;
or the two vision trunks against each other (`--compare-trunks`).

    python -m pipelines.bench.policy_train_step [--batch-size 30] [--steps 3] [--threads N]
    python -m pipelines.bench.policy_train_step --compare-trunks [--rounds 3] [--threads 2]

Prints: seconds per training step (forward + backward + Adam + EMA update; batch 30, 4 demo + 7 observation
frames at 100x180, 2 attention layers, contrastive before and after attention), peak resident memory, and the
time of the attention stack alone on the same features in the same run: the MOSAIC pattern through its fused
attention kernel (training's path), the MOSAIC pattern through the explicit computation that also returns the
attention maps (`return_weights=True`, what recording an episode uses), and the full spatio-temporal pattern
(T-OSIL style: observation frames attend causally to all observation frames besides the demo), with the ratios
MOSAIC/full and fused/explicit. The three are timed in interleaved rounds so that load from other processes
falls on all of them alike.

`--compare-trunks`: a full MOSAIC training step (the same, with its default 7 observation + 4 demo frames) at
the `cpu` preset's sizes (batch 16, 48x88 unless given) with `--policy.vision_backbone=resnet18` and with
`conv` (256 channels, and 128: `--policy.conv_channels=128`), in alternating rounds (one warm-up round
first); prints each one's parameters, median ms per step, the
ratio, and where a step's time goes, each part timed alone on the step's sizes: the online trunk's forward +
backward and the EMA target trunk's forward (batch x 11 frames), the online attention stack's forward + backward
and the target attention's forward, the four augmentation calls (two views of demo and observation frames), and
the rest (embeddings, heads, losses, contrastive modules, Adam, EMA update) as the step minus those (timed apart,
so an estimate). Each figure in wall time and in this process's CPU time; with `--threads 1` the CPU time is
what load from other processes leaves alone (on a busy 2-core machine, 2 threads wait on each other in every
small operation and the augmentations' many small ones can take seconds).
"""

import argparse
import contextlib
import resource
import statistics
import time

import torch

from mosaic_data.constants import (
    ACTION_DIM,
    ACTION_KEY,
    CAMERA_KEY,
    DEMO_FRAMES_KEY,
    STATE_DIM,
    STATE_KEY,
    policy_features,
)


def paper_config(height: int, width: int, **overrides):
    from mosaic_policy import MosaicConfig

    return MosaicConfig(device="cpu", **policy_features(height, width), push_to_hub=False, **overrides)


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


def train_step(policy, optimizer, batch: dict) -> None:
    """One lerobot-train update: forward, backward, Adam, then the policy's post-step update (the EMA target)."""
    loss, _ = policy.forward(batch)
    optimizer.zero_grad()
    loss.backward()
    optimizer.step()
    policy.update()


def time_train_steps(batch_size: int, steps: int, height: int, width: int) -> list[float]:
    from mosaic_policy.mosaic.modeling_mosaic import MosaicPolicy

    config = paper_config(height, width)
    policy = MosaicPolicy(config).train()
    optimizer = torch.optim.Adam(policy.get_optim_params(), lr=config.optimizer_lr)
    batch = synthetic_batch(config, batch_size, height, width)
    times = []
    for _ in range(steps + 1):  # the first step warms up oneDNN
        start = time.perf_counter()
        train_step(policy, optimizer, batch)
        times.append(time.perf_counter() - start)
    return times[1:]


TRUNK_VARIANTS = {
    "resnet18": {"vision_backbone": "resnet18"},
    "conv": {"vision_backbone": "conv"},
    "conv 128": {"vision_backbone": "conv", "conv_channels": 128},
}
"""The models --compare-trunks times: the paper's trunk, the conv trunk at the same 256 channels, and the conv
trunk at 128 channels (`--policy.conv_channels=128`: attention, embedding and heads at that width)."""

TRUNK_PARTS = ("step", "trunk fwd+bwd", "target trunk fwd", "attention fwd+bwd", "target attention fwd", "augmentation")


def compare_trunks(batch_size: int, height: int, width: int, rounds: int) -> dict[str, dict]:
    """Per vision backbone: parameters of its trunk and median seconds of a full MOSAIC training step and of its
    parts (TRUNK_PARTS), timed in alternating rounds after one warm-up round."""
    from mosaic_policy.mosaic.modeling_mosaic import MosaicPolicy

    runs = {}
    for name, overrides in TRUNK_VARIANTS.items():
        torch.manual_seed(0)
        config = paper_config(height, width, **overrides)
        policy = MosaicPolicy(config).train()
        runs[name] = (policy, torch.optim.Adam(policy.get_optim_params(), lr=config.optimizer_lr))
    batch = synthetic_batch(config, batch_size, height, width)
    d, t = config.n_demo_frames, config.train_obs_frames
    frames = torch.rand(batch_size * (d + t), 3, height, width)
    features = {}  # per variant, demo and observation features of its width for the attention's timing
    for name, (policy, _) in runs.items():
        c, h, w = policy.model.feature_shape
        features[name] = (torch.randn(batch_size, c, d, h, w, requires_grad=True),
                          torch.randn(batch_size, c, t, h, w, requires_grad=True))
    times = {backbone: {part: [] for part in TRUNK_PARTS} for backbone in runs}  # (wall s, CPU s) per round
    for round_ in range(rounds + 1):  # the first round warms up oneDNN
        for backbone, (policy, optimizer) in runs.items():
            demo_features, obs_features = features[backbone]
            took = {}
            with _timed(took, "step"):
                train_step(policy, optimizer, batch)
            with _timed(took, "trunk fwd+bwd"):
                policy.model.trunk(frames).sum().backward()
            policy.model.trunk.zero_grad(set_to_none=True)
            with _timed(took, "target trunk fwd"), torch.no_grad():
                policy.target_trunk(frames)
            with _timed(took, "attention fwd+bwd"):
                demo_out, obs_out, _ = policy.model.attention(demo_features, obs_features, False)
                (demo_out.sum() + obs_out.sum()).backward()
            policy.model.attention.zero_grad(set_to_none=True)
            demo_features.grad = obs_features.grad = None
            with _timed(took, "target attention fwd"), torch.no_grad():
                policy.target_attention(demo_features, obs_features, False)
            with _timed(took, "augmentation"):
                for _ in range(2):  # view 1 (the online branch) and view 2 (the target branch)
                    policy.augment(batch[DEMO_FRAMES_KEY]), policy.augment(batch[CAMERA_KEY])
            if round_:
                for part, seconds in took.items():
                    times[backbone][part].append(seconds)
    return {
        backbone: {
            "params": sum(p.numel() for p in policy.model.trunk.parameters()),
            "policy_params": sum(p.numel() for p in policy.parameters()),
            **{part: statistics.median(s[0] for s in seconds) for part, seconds in times[backbone].items()},
            **{f"{part} cpu": statistics.median(s[1] for s in seconds) for part, seconds in times[backbone].items()},
        }
        for backbone, (policy, _) in runs.items()
    }


@contextlib.contextmanager
def _timed(took: dict, part: str):
    """Store (wall seconds, this process's CPU seconds) of the block under took[part]."""
    wall, cpu = time.perf_counter(), time.process_time()
    yield
    took[part] = (time.perf_counter() - wall, time.process_time() - cpu)


def print_trunk_comparison(results: dict[str, dict], batch_size: int, height: int, width: int, rounds: int) -> None:
    print(
        f"MOSAIC training step, batch {batch_size}, 4 demo + 7 observation frames at {height}x{width}, contrastive "
        f"both, {torch.get_num_threads()} threads (median of {rounds} alternating rounds; wall time, and this "
        f"process's CPU time, which load from other processes does not inflate):"
    )
    for backbone, r in results.items():
        print(
            f"  {backbone:<9}: {r['step'] * 1e3:.0f} ms/step wall, {r['step cpu'] * 1e3:.0f} ms CPU; trunk "
            f"{r['params'] / 1e6:.2f} M params (policy {r['policy_params'] / 1e6:.2f} M)"
        )
        for clock, suffix in (("wall", ""), ("CPU", " cpu")):
            step = r[f"step{suffix}"]
            rest = step - sum(r[part + suffix] for part in TRUNK_PARTS[1:])
            parts = [(part, r[part + suffix]) for part in TRUNK_PARTS[1:]] + [("rest", rest)]
            print(f"    {clock:<4} " + ", ".join(f"{part} {s * 1e3:.0f} ms ({s / step:.0%})" for part, s in parts))
    old = results["resnet18"]
    for name, new in results.items():
        if name == "resnet18":
            continue
        print(
            f"  {name} vs resnet18: {old['step'] / new['step']:.2f}x faster per step (wall), "
            f"{old['step cpu'] / new['step cpu']:.2f}x (CPU); trunk fwd+bwd "
            f"{old['trunk fwd+bwd'] / new['trunk fwd+bwd']:.1f}x (wall), target trunk fwd "
            f"{old['target trunk fwd'] / new['target trunk fwd']:.1f}x (wall); trunk parameters "
            f"{old['params'] / new['params']:.1f}x fewer"
        )


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
    parser.add_argument("--batch-size", type=int, default=None, help="default 30 (16 with --compare-trunks)")
    parser.add_argument("--steps", type=int, default=3, help="timed steps after one warm-up step")
    parser.add_argument("--height", type=int, default=None, help="default 100 (48 with --compare-trunks)")
    parser.add_argument("--width", type=int, default=None, help="default 180 (88 with --compare-trunks)")
    parser.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's choice)")
    parser.add_argument("--attention-repeats", type=int, default=3, help="timed rounds of the attention comparison")
    parser.add_argument("--skip-train", action="store_true", help="only the attention comparison")
    parser.add_argument("--compare-trunks", action="store_true",
                        help="time a training step with each vision backbone (resnet18, conv) instead")
    parser.add_argument("--rounds", type=int, default=3, help="timed alternating rounds of --compare-trunks")
    args = parser.parse_args()
    sizes = (16, 48, 88) if args.compare_trunks else (30, 100, 180)
    for name, default in zip(("batch_size", "height", "width"), sizes, strict=True):
        if getattr(args, name) is None:
            setattr(args, name, default)
    if args.threads:
        torch.set_num_threads(args.threads)
    device = "cuda" if torch.cuda.is_available() else "cpu"
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, device for this run: cpu (cuda available: {device == 'cuda'})")
    if args.compare_trunks:
        results = compare_trunks(args.batch_size, args.height, args.width, args.rounds)
        print_trunk_comparison(results, args.batch_size, args.height, args.width, args.rounds)
        print(f"peak resident memory: {peak_rss_gib():.2f} GiB")
        return

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
