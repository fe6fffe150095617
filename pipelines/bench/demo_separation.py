"""Does a trained MOSAIC tell unseen demonstrations apart? Its demonstration vectors, training demos against fresh ones.

    python -m pipelines.bench.demo_separation --policy.path CHECKPOINT --data-dir DIR --task door \
        [--variations 0,1,2,3] [--demos 20] [--fresh 10]

MOSAIC's demonstration stream (trunk, attention over the demonstration frames, frame embedding) ends in the vectors
its heads read: the demonstration embedding, and with ``demo_summary`` the summary, with ``variation_loss_weight``
the variation projection. For each variation, the first ``--demos`` Sawyer demonstrations of DIR/mosaic/<task>_sawyer
(what it trained on) give a centroid per vector; ``--fresh`` new demonstrations by the Sawyer expert, at the seeds
``mosaic-eval`` gives its episodes (instances it never saw), are each assigned the variation of the nearest
centroid. A row per vector: how many training and fresh demonstrations land on their own variation.

An agent that does another variation than the one it was shown either misread the demonstration (fresh
demonstrations land on a wrong centroid here) or read it and failed to act on it (they land right here):
``mosaic-eval``'s confusion matrix cannot tell the two apart, this can.
"""

from __future__ import annotations

import numpy as np
import torch

from .demo_dependence import bench_parser, demonstrated_variations, episodes_of, load_policy, open_dataset


@torch.no_grad()
def demo_vectors(policy, frames: torch.Tensor | np.ndarray) -> dict[str, np.ndarray]:
    """The vectors MOSAIC's heads read from one demonstration (all its frames, (N, 3, H, W) or (N, H, W, 3)): the
    policy picks its demonstration frames as ``set_demo`` does."""
    from mosaic_policy.common.demo_conditioning import to_float_frames
    from mosaic_policy.common.paired_sampling import demo_frame_indices

    model = policy.acting_model
    frames = to_float_frames(frames)
    frames = frames[demo_frame_indices(frames.shape[0], policy.config.n_demo_frames)][None].to(policy.device)
    demo_out, _ = model.attend_demo(model.trunk, frames)
    embedding = model.frame_embeddings(demo_out).flatten(1)
    vectors = {"demonstration embedding": embedding}
    if model.summary is not None:
        vectors["summary (demo_summary)"] = model.summarize_demo(demo_out)
    if model.variation_projector is not None:
        vectors["variation projection (variation_loss_weight)"] = torch.nn.functional.normalize(
            model.variation_projector(embedding), dim=-1
        )
    return {name: vector[0].cpu().numpy() for name, vector in vectors.items()}


def nearest_centroid(train: dict[int, list[np.ndarray]], queries: dict[int, list[np.ndarray]]) -> np.ndarray:
    """Confusion (variations x variations): row the demonstrated variation, column the variation of the training
    centroid nearest to each query vector."""
    order = sorted(train)
    centroids = np.stack([np.mean(train[v], axis=0) for v in order])
    confusion = np.zeros((len(order), len(order)), dtype=int)
    for row, variation in enumerate(order):
        for vector in queries[variation]:
            confusion[row, int(np.argmin(((centroids - vector) ** 2).sum(axis=1)))] += 1
    return confusion


def fresh_demonstrations(task: str, variation: int, count: int, image_hw: tuple[int, int]):
    """``count`` new Sawyer expert demonstrations of ``variation``, all frames, at the first ``count`` evaluation
    episodes' demonstration seeds (``mosaic-eval``'s default ``--seed``)."""
    from mosaic_data.constants import EVAL_BASE_SEED
    from pipelines.evaluation.demo_sources import ExpertDemoSource
    from pipelines.evaluation.seeds import episode_seed, episode_seeds

    source = ExpertDemoSource(image_hw=image_hw)
    try:
        for episode in range(count):
            seed = episode_seeds(episode_seed(EVAL_BASE_SEED, episode), variation).demo
            yield source.demonstration(task, variation, seed, None).frames
    finally:
        source.close()


def separation_table(policy, task: str, train_demos: dict[int, list[torch.Tensor]], fresh: int) -> list[tuple[str, str, str, str]]:
    """Rows (vector, training demos on their own centroid, fresh demos on it, fresh per variation)."""
    image_hw = tuple(next(iter(train_demos.values()))[0].shape[-2:])
    train = {v: [demo_vectors(policy, frames) for frames in demos] for v, demos in train_demos.items()}
    new = {v: [demo_vectors(policy, frames) for frames in fresh_demonstrations(task, v, fresh, image_hw)] for v in train_demos}
    rows = []
    for name in next(iter(train.values()))[0]:
        train_of = {v: [vectors[name] for vectors in train[v]] for v in train}
        on_train = nearest_centroid(train_of, train_of)
        on_fresh = nearest_centroid(train_of, {v: [vectors[name] for vectors in new[v]] for v in new})
        per_variation = ", ".join(f"{v}: {on_fresh[i, i]}/{on_fresh[i].sum()}" for i, v in enumerate(sorted(train)))
        rows.append((name, f"{np.trace(on_train)}/{on_train.sum()}", f"{np.trace(on_fresh)}/{on_fresh.sum()}", per_variation))
    return rows


def main(argv: list[str] | None = None) -> None:
    parser = bench_parser(__doc__, "holds mosaic/<task>_sawyer")
    parser.add_argument("--variations", default="", help="variation indices, comma-separated (default: all)")
    parser.add_argument("--demos", type=int, default=20, help="training demonstrations per variation (the centroids)")
    parser.add_argument("--fresh", type=int, default=10, help="new expert demonstrations per variation")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    variations = demonstrated_variations("demo_separation", args.task, args.variations)
    dataset = open_dataset("demo_separation", args.data_dir, args.task, "sawyer")
    policy = load_policy(args.policy_path).policy
    if getattr(policy, "name", None) != "mosaic":
        raise SystemExit(
            f"demo_separation: {args.policy_path} is a {getattr(policy, 'name', type(policy).__name__)} policy; it reads "
            "MOSAIC's demonstration stream: give a --policy.type=mosaic checkpoint."
        )
    train_demos = {v: [episode[0] for episode in episodes_of(dataset, v, args.demos)] for v in variations}
    rows = separation_table(policy, args.task, train_demos, args.fresh)
    shown = {v: len(demos) for v, demos in train_demos.items()}
    print(f"\n{args.task}, variations {variations}: centroids of {min(shown.values())}-{max(shown.values())} training "
          f"demonstrations each; {args.fresh} fresh expert demonstrations per variation")
    print("| demonstration vector | training demos on their own centroid | fresh demos on their own centroid | fresh, per variation |")
    print("|---|---|---|---|")
    for row in rows:
        print("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    main()
