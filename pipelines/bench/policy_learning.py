"""Benchmark: does MOSAIC learn, and does it use the demonstration? A short CPU run on collected door data.

    python -m pipelines.bench.policy_learning [--task door] [--variations 0 1] [--episodes 4] [--steps 300]
        [--eval-every 500] [--data-dir DIR] [--save-checkpoint DIR]

Collects expert episodes of the door task with the Panda (agent) and the Sawyer (demonstrator) at a reduced
image size (mosaic_data's experts, LeRobot's writer), holds out the last Panda episode of every variation,
trains with the same steps as lerobot-train (dataset stats normalisation, paired demos, Adam, update()), and
prints the held-out BC loss before and after, and the held-out action error given a demo of the right
variation against a demo of another one, over all frames and over the first `--early-frames` frames of each
episode (before the arm's motion gives the goal away). Variations 0 and 1 are the same door swung opposite
ways: only the demonstration tells them apart.

The demonstrations of the held-out figures are held out too (the last `--held-out-demos` demonstrator episodes
of every variation never condition a training sample), so they measure one-shot use of new demonstrations.

`--eval-every` prints the held-out figures during training (how the demo dependence grows with steps);
`--data-dir` keeps the collected datasets for the next run; `--save-checkpoint` writes the trained policy
with its processors in lerobot-train's `pretrained_model` layout, so `mosaic-eval --policy.path=DIR` rolls it out.
"""

import argparse
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

IMAGE_KEY = "observation.images.agentview"


def collect(root: Path, repo_id: str, task: str, robot: str, variations, episodes: int, height: int, width: int) -> Path:
    from lerobot.datasets import LeRobotDataset

    from mosaic_data.rollout import run_expert_episode
    from mosaic_data.tasks import make_task_env

    from mosaic_data.collection.schema import dataset_features

    features = dataset_features(height, width)
    dataset = LeRobotDataset.create(repo_id, 20, features, root=root, use_videos=True)
    for variation in variations:
        env = make_task_env(task, variation, robot, image_height=height, image_width=width)
        kept, seed = 0, 0
        while kept < episodes and seed < 3 * episodes:
            episode = run_expert_episode(env, seed, record_frames=True)
            seed += 1
            if not episode.success:
                continue
            for i in range(episode.length):
                dataset.add_frame(
                    {
                        IMAGE_KEY: episode.frames[i],
                        "observation.state": np.asarray(episode.states[i], dtype=np.float32),
                        "action": np.asarray(episode.actions[i], dtype=np.float32),
                        "variation": np.array([variation]),
                        "next.success": np.array([episode.successes[i]]),
                        "next.done": np.array([i == episode.length - 1]),
                        "task": episode.description,
                    }
                )
            dataset.save_episode()
            kept += 1
        env.close()
    dataset.finalize()
    return root


def hold_out_demos(sampler, per_variation: int, agent_meta):
    """Move the last ``per_variation`` demonstrator episodes of every variation out of the training ``sampler``
    and into a new (synchronous) sampler for the held-out figures, before the training sampler draws anything."""
    from mosaic_policy.paired_sampling import PairedDemoSampler

    if per_variation < 1:
        raise SystemExit("--held-out-demos must be at least 1")
    held_out = PairedDemoSampler(sampler.repo_id, sampler.meta.root, sampler.image_key, sampler.n_frames, agent_meta, threads=0)
    for task, episodes in sampler.episodes_by_task.items():
        if len(episodes) <= per_variation:
            raise SystemExit(f"variation {task!r} has {len(episodes)} demonstrator episodes: use more --episodes")
        sampler.episodes_by_task[task], held_out.episodes_by_task[task] = episodes[:-per_variation], episodes[-per_variation:]
    return held_out


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="door")
    parser.add_argument("--variations", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--episodes", type=int, default=4, help="per variation and robot")
    parser.add_argument("--height", type=int, default=48)
    parser.add_argument("--width", type=int, default=88)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--batch-size", type=int, default=8)
    parser.add_argument("--obs-frames", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--early-frames", type=int, default=10, help="frames counted as 'early' in the error table")
    parser.add_argument("--held-out-demos", type=int, default=2,
                        help="demonstrator episodes per variation kept out of training, for the held-out figures")
    parser.add_argument("--eval-every", type=int, default=0, help="also print the held-out figures every N steps")
    parser.add_argument("--data-dir", type=Path, help="collect into (or reuse) this folder instead of a temporary one")
    parser.add_argument("--save-checkpoint", type=Path, help="write the trained policy and processors here")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)

    from lerobot.datasets import LeRobotDataset
    from lerobot.policies.factory import make_policy

    from mosaic_policy import MosaicConfig
    from mosaic_policy.processor_mosaic import make_mosaic_pre_post_processors

    from mosaic_data.collection.quiet import quiet_dataset_writing

    quiet_dataset_writing()

    agent_repo, demo_repo = f"mosaic/{args.task}_panda", f"mosaic/{args.task}_sawyer"
    with tempfile.TemporaryDirectory() as tmp:
        data_dir = args.data_dir or Path(tmp)
        name = f"{args.task}_v{'-'.join(map(str, args.variations))}_e{args.episodes}_{args.height}x{args.width}"
        agent_root, demo_root = data_dir / name / "agent", data_dir / name / "demo"
        if (agent_root / "meta" / "info.json").exists() and (demo_root / "meta" / "info.json").exists():
            print(f"reusing the datasets in {data_dir / name}")
        else:
            start = time.perf_counter()
            for root in (agent_root, demo_root):  # a half-written earlier attempt
                shutil.rmtree(root, ignore_errors=True)
            collect(agent_root, agent_repo, args.task, "panda", args.variations, args.episodes, args.height, args.width)
            collect(demo_root, demo_repo, args.task, "sawyer", args.variations, args.episodes, args.height, args.width)
            print(f"collected {args.task} variations {args.variations}, {args.episodes} episodes each per robot, in {time.perf_counter() - start:.0f} s")

        from lerobot.datasets import LeRobotDatasetMetadata

        meta = LeRobotDatasetMetadata(agent_repo, root=agent_root)
        tasks = [t[0] for t in meta.episodes["tasks"]]
        held_out = [max(i for i, t in enumerate(tasks) if t == task) for task in dict.fromkeys(tasks)]
        train_episodes = [i for i in range(meta.total_episodes) if i not in held_out]

        config = MosaicConfig(
            device="cpu",
            push_to_hub=False,
            demo_repo_id=demo_repo,
            demo_root=str(demo_root),
            train_obs_frames=args.obs_frames,
            ema_total_steps=args.steps,
            demo_loader_threads=1,
        )
        deltas = [i / meta.fps for i in config.observation_delta_indices]
        delta_timestamps = {IMAGE_KEY: deltas, "observation.state": deltas, "action": deltas}
        train_set = LeRobotDataset(agent_repo, root=agent_root, episodes=train_episodes, delta_timestamps=delta_timestamps)
        eval_set = LeRobotDataset(agent_repo, root=agent_root, episodes=held_out, delta_timestamps=delta_timestamps)
        policy = make_policy(config, ds_meta=train_set.meta)
        preprocessor, postprocessor = make_mosaic_pre_post_processors(config, dataset_stats=train_set.meta.stats)
        optimizer = torch.optim.Adam(policy.get_optim_params(), lr=config.optimizer_lr)
        sampler = policy.demo_sampler
        eval_sampler = hold_out_demos(sampler, args.held_out_demos, train_set.meta)
        other_task = {t: next(o for o in dict.fromkeys(tasks) if o != t) for t in dict.fromkeys(tasks)}

        eval_batches = [preprocessor(b) | {"frame_index": b["frame_index"]} for b in torch.utils.data.DataLoader(eval_set, batch_size=16)]
        for batch in eval_batches:
            batch["right_demo"] = eval_sampler.sample(list(batch["task"]), batch["episode_index"].tolist()).float() / 255
            batch["wrong_demo"] = eval_sampler.sample([other_task[t] for t in batch["task"]]).float() / 255

        stats = {key: {name: torch.as_tensor(value, dtype=torch.float32)[:3] for name, value in train_set.meta.stats[key].items()}
                 for key in ("action", "observation.state")}

        def target_metres(normalised_action):  # MIN_MAX back to metres, position only
            low, high = stats["action"]["min"], stats["action"]["max"]
            return (normalised_action[..., :3].clamp(-1, 1) + 1) / 2 * (high - low) + low

        @torch.no_grad()
        def evaluate():
            policy.eval()
            nll, n, n_early = 0.0, 0, 0
            errors = {f"{key}{part}": 0.0 for key in ("right", "wrong", "step_right", "step_wrong") for part in ("", "_early")}
            for batch in eval_batches:
                valid = ~batch["action_is_pad"]
                early = valid & (batch["frame_index"][:, None] + torch.arange(valid.shape[1]) < args.early_frames)
                position = batch["observation.state"][..., :3] * stats["observation.state"]["std"] + stats["observation.state"]["mean"]
                true_step = target_metres(batch["action"]) - position
                for key, demo in (("right", batch["right_demo"]), ("wrong", batch["wrong_demo"])):
                    encoded = policy.model.encode(policy.model.trunk, policy.model.attention, demo, batch[IMAGE_KEY])
                    embeddings = policy.model.frame_embeddings(encoded["obs_post"])
                    dist = policy.model.action_distribution(embeddings, batch["observation.state"])
                    error = (dist.mode() - batch["action"].clamp(-1, 1)).abs().mean(-1)
                    errors[key] += error[valid].sum().item()
                    errors[f"{key}_early"] += error[early].sum().item()
                    # The commanded step (target minus current grip position), in mm: the action is an absolute
                    # target a little ahead of the hand, so its error above is mostly the state's; the step is
                    # where the goal shows.
                    step_error = 1000 * torch.linalg.vector_norm(target_metres(dist.mode()) - position - true_step, dim=-1)
                    errors[f"step_{key}"] += step_error[valid].sum().item()
                    errors[f"step_{key}_early"] += step_error[early].sum().item()
                    if key == "right":
                        nll += -dist.log_prob(batch["action"]).sum(-1)[valid].sum().item()
                n += valid.sum().item()
                n_early += early.sum().item()
            policy.train()
            return nll / n, {k: v / (n_early if k.endswith("early") else n) for k, v in errors.items()}

        def report(when: str, figures) -> None:
            nll, errors = figures
            print(
                f"{when}: held-out BC loss {nll:.2f} nats; right demo / demo of another variation: action error (mean "
                f"|a - a*|, normalised [-1, 1] units) all frames {errors['right']:.3f} / {errors['wrong']:.3f}, first "
                f"{args.early_frames} frames {errors['right_early']:.3f} / {errors['wrong_early']:.3f}; commanded-step "
                f"error (|predicted - expert| of target minus grip position, mm) all frames {errors['step_right']:.1f} / "
                f"{errors['step_wrong']:.1f}, first {args.early_frames} frames {errors['step_right_early']:.1f} / "
                f"{errors['step_wrong_early']:.1f}",
                flush=True,
            )

        before = evaluate()
        loader = torch.utils.data.DataLoader(train_set, batch_size=args.batch_size, shuffle=True, drop_last=True)
        step, start, eval_seconds = 0, time.perf_counter(), 0.0
        while step < args.steps:
            for batch in loader:
                loss, info = policy.forward(preprocessor(batch))
                optimizer.zero_grad()
                loss.backward()
                torch.nn.utils.clip_grad_norm_(policy.get_optim_params(), 10.0)
                optimizer.step()
                policy.update()
                step += 1
                if step % 50 == 0:
                    print(f"step {step}: loss {info['loss']:.2f} (bc {info['bc_loss']:.2f}), {(time.perf_counter() - start - eval_seconds) / step:.2f} s/step")
                if args.eval_every and step % args.eval_every == 0 and step < args.steps:
                    eval_start = time.perf_counter()
                    report(f"after {step} steps", evaluate())
                    eval_seconds += time.perf_counter() - eval_start
                if step >= args.steps:
                    break
        after = evaluate()
        sampler.close()
        print(f"held-out BC loss (nats per step, 7 dims): {before[0]:.2f} before -> {after[0]:.2f} after {args.steps} steps")
        report("before training", before)
        report(f"after {args.steps} steps", after)
        if args.save_checkpoint:
            for part in (policy, preprocessor, postprocessor):
                part.save_pretrained(args.save_checkpoint)
            print(f"saved the trained policy to {args.save_checkpoint} (mosaic-eval --policy.path={args.save_checkpoint})")


if __name__ == "__main__":
    main()
