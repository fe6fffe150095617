"""Multi-process training: `accelerate launch --num_processes 2 ... lerobot-train` on CPU (gloo), and its parts.

The end-to-end run starts LeRobot's own lerobot-train in two processes through ``ddp_probe.py``, which records
per rank what the rank trained on and paired and its final policy state (see its docstring). On CPU the
launcher is ``--multi_gpu`` with ``--policy.device=cpu``: ``accelerate launch --cpu --num_processes 2`` starts
ONE process (accelerate's CPU launcher leaves multi-process CPU runs to mpirun), which the first assertion
would catch.
"""

import importlib.metadata
import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.torch import load_file

from lerobot.datasets import LeRobotDatasetMetadata
from mosaic_policy.common import distributed
from mosaic_policy.common.paired_sampling import PairedDemoSampler
from tests.helpers.policy import IMAGE_KEY, POLICY_TYPES, read_variation_rank, small_flags, variation_description

BIN = Path(sys.executable).parent
PROBE = Path(__file__).parent / "ddp_probe.py"
STEPS, BATCH, SEED = 3, 4, 1000  # SEED: lerobot-train's default --seed


def _accelerate_available() -> bool:
    names = {d.metadata.get("Name") for d in importlib.metadata.distributions()}
    return "lerobot_policy_mosaic" in names and (BIN / "accelerate").exists()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


BASELINES = [t for t in POLICY_TYPES if t != "mosaic"]


def _launch_two_processes(policy_type: str, options: list[str], door_datasets, base: Path) -> dict:
    """`accelerate launch` of lerobot-train (through ddp_probe.py) in 2 CPU processes; what each rank recorded."""
    if not _accelerate_available():
        pytest.skip("needs accelerate and the installed lerobot_policy_mosaic plugin (README set-up)")
    agent_root, demo_root = door_datasets
    output, probe = base / "run", base / "probe"
    command = [
        str(BIN / "accelerate"), "launch", "--multi_gpu", "--num_processes", "2", "--num_machines", "1",
        "--mixed_precision", "no", "--dynamo_backend", "no", "--main_process_port", str(_free_port()),
        str(PROBE),
        f"--policy.type={policy_type}", "--dataset.repo_id=mosaic/door_panda", f"--dataset.root={agent_root}",
        "--policy.demo_repo_id=mosaic/door_sawyer", f"--policy.demo_root={demo_root}",
        "--policy.push_to_hub=false", "--policy.device=cpu", f"--steps={STEPS}", f"--batch_size={BATCH}",
        "--num_workers=0", f"--save_freq={STEPS}", "--log_freq=1", f"--output_dir={output}", f"--seed={SEED}",
        "--policy.train_obs_frames=3", "--policy.embed_dim=32", "--policy.head_hidden_dim=32",
        "--policy.demo_loader_threads=2", *options,
    ]  # fmt: skip
    env = {
        **os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled", "OMP_NUM_THREADS": "1",
        "MOSAIC_DDP_PROBE_DIR": str(probe),
    }  # fmt: skip
    result = subprocess.run(command, check=False, cwd=base, env=env, capture_output=True, text=True, timeout=400)
    log = result.stdout + result.stderr
    assert result.returncode == 0, log[-4000:]
    assert f"Effective batch size: {BATCH} x 2 = {2 * BATCH}" in log  # two processes, not one
    ranks = [json.loads((probe / f"rank{r}.json").read_text()) for r in (0, 1)]
    states = [load_file(probe / f"rank{r}.safetensors") for r in (0, 1)]
    return {"output": output, "ranks": ranks, "states": states, "agent_root": agent_root}


def _assert_one_checkpoint_with_the_state_of_every_rank(run: dict) -> None:
    states = run["states"]
    checkpoints = run["output"] / "checkpoints"
    assert sorted(p.name for p in checkpoints.iterdir()) == [f"{STEPS:06d}", "last"]
    saved = load_file(checkpoints / "last" / "pretrained_model" / "model.safetensors")
    assert saved.keys() == states[0].keys() == states[1].keys()
    differ = [k for k in saved if not (torch.equal(states[0][k], states[1][k]) and torch.equal(saved[k], states[0][k]))]
    assert differ == []  # parameters, EMA target, BatchNorm statistics: identical on both ranks and saved once
    assert all(r["updates"] == STEPS for r in run["ranks"])  # lerobot-train called update() after every step


@pytest.fixture(scope="module")
def two_process_run(door_datasets, tmp_path_factory):
    """One 2-process MOSAIC run, shared by the tests below."""
    return _launch_two_processes("mosaic", small_flags("mosaic"), door_datasets, tmp_path_factory.mktemp("two_process"))


@pytest.mark.slow
@pytest.mark.parametrize("policy_type", BASELINES)
def test_every_baseline_trains_in_two_processes_to_one_checkpoint_and_identical_ranks(policy_type, door_datasets, tmp_path):
    """The baselines share MOSAIC's multi-process path (one run each, hence slow; MOSAIC's run covers the path)."""
    _assert_one_checkpoint_with_the_state_of_every_rank(
        _launch_two_processes(policy_type, small_flags(policy_type), door_datasets, tmp_path)
    )


def test_two_processes_write_one_checkpoint_holding_the_state_every_rank_ends_with(two_process_run):
    """Every parameter and buffer of the checkpoint equals each rank's final state, the EMA target's copies and the
    BatchNorm statistics included: the statistics come from both ranks' shards, not rank 0's half of the samples."""
    _assert_one_checkpoint_with_the_state_of_every_rank(two_process_run)


def test_two_processes_update_the_ema_target_identically_after_every_step(two_process_run):
    ranks, saved = two_process_run["ranks"], two_process_run["states"][0]
    assert all(r["updates"] == STEPS for r in ranks)  # lerobot-train called update() on the unwrapped policy
    assert int(saved["ema_step"]) == STEPS
    target_keys = [k for k in saved if k.startswith(("target_trunk.", "target_attention."))]
    assert target_keys and any("running_mean" in k for k in target_keys)
    online_of = {k: k.replace("target_trunk.", "model.trunk.", 1).replace("target_attention.", "model.attention.", 1) for k in target_keys}  # fmt: skip
    weights = [k for k in target_keys if k.endswith(".weight")]
    assert any(not torch.equal(saved[k], saved[online_of[k]]) for k in weights)  # momentum < 1: target lags online
    for k in target_keys:
        if "running" in k:  # the target's BatchNorm statistics are the online ones, averaged over the ranks
            assert torch.equal(saved[k], saved[online_of[k]])


def test_each_rank_pairs_the_samples_of_its_own_shard_each_once(two_process_run):
    """Rank r's k-th batch is global batch 2k + r of lerobot-train's data order; over the ranks every sample is
    paired once, each with a demonstration of its own variation."""
    from lerobot.datasets import EpisodeAwareSampler

    ranks = two_process_run["ranks"]
    meta = LeRobotDatasetMetadata("mosaic/door_panda", root=two_process_run["agent_root"])
    order = list(EpisodeAwareSampler(meta.episodes["dataset_from_index"], meta.episodes["dataset_to_index"], shuffle=True, seed=SEED))  # fmt: skip
    episode_of = np.repeat(np.arange(meta.total_episodes), meta.episodes["length"])
    episode_tasks = [t[0] for t in meta.episodes["tasks"]]
    for r, rank in enumerate(ranks):
        assert len(rank["batches"]) == STEPS
        for k, batch in enumerate(rank["batches"]):
            assert batch["index"] == order[(2 * k + r) * BATCH : (2 * k + r + 1) * BATCH]
            assert batch["task"] == [episode_tasks[episode_of[i]] for i in batch["index"]]
            assert [variation_description(v) for v, _ in batch["demo"]] == batch["task"]
    all_indices = [i for rank in ranks for b in rank["batches"] for i in b["index"]]
    assert sorted(all_indices) == sorted(order[: 2 * STEPS * BATCH])


def test_the_loss_is_balanced_over_the_global_batch_as_in_one_process(two_process_run):
    """The per-variation loss balance of the global batch (both ranks' shards), as one process training on it would
    weigh it, not each rank's shard balanced on its own and then averaged by DDP (different weights)."""
    from mosaic_policy.common.demo_conditioning import balanced_sample_weights

    ranks = two_process_run["ranks"]
    for k in range(STEPS):
        tasks = ranks[0]["batches"][k]["task"] + ranks[1]["batches"][k]["task"]
        weights = torch.tensor(ranks[0]["weights"][k] + ranks[1]["weights"][k]) / 2  # DDP averages the 2 ranks
        assert torch.allclose(weights, balanced_sample_weights(tasks)), k


def test_each_rank_draws_its_own_demonstrations_and_augmentations(two_process_run):
    """The ranks' demonstrator samplers have different seeds and torch's streams (augmentations, contrastive
    positives, dropout) differ: the i-th samples of two ranks do not get the same random draws."""
    ranks = two_process_run["ranks"]
    assert [r["sampler"]["process_index"] for r in ranks] == [0, 1]
    assert ranks[0]["sampler"]["spawn_key"] != ranks[1]["sampler"]["spawn_key"]
    assert all(a != b for a, b in zip(ranks[0]["rng_digests"], ranks[1]["rng_digests"], strict=True))


def test_each_process_decodes_with_its_share_of_the_cores(two_process_run):
    """Each of the 2 processes starts at most its share of the machine's cores of the 2 decode threads asked for."""
    expected = max(1, min(2, distributed.usable_cpus() // 2))
    assert [r["sampler"]["threads"] for r in two_process_run["ranks"]] == [expected] * 2


def _draws(sampler: PairedDemoSampler, task: str, n: int = 12) -> list:
    return [sampler._draw(task, None) for _ in range(n)]


def test_samplers_of_two_processes_draw_different_demonstrations(door_datasets):
    """Every process builds its sampler with the same seed, yet no two ranks draw the same demonstrations and frames
    in the same order. Process 0 keeps the single-process stream."""
    agent_root, demo_root = door_datasets
    meta = LeRobotDatasetMetadata("mosaic/door_panda", root=agent_root)

    def sampler(process_index):
        s = PairedDemoSampler("mosaic/door_sawyer", demo_root, IMAGE_KEY, 4, meta, threads=0, process_index=process_index)
        s.observe(list(range(meta.total_episodes)))
        return s

    task = variation_description(1)
    first, second = sampler(0), sampler(1)
    assert _draws(first, task) != _draws(second, task)
    single = PairedDemoSampler("mosaic/door_sawyer", demo_root, IMAGE_KEY, 4, meta, threads=0)
    single.observe(list(range(meta.total_episodes)))
    assert _draws(sampler(0), task) == _draws(single, task)


def test_two_simulated_ranks_pair_each_sample_of_their_own_shard_once(door_datasets):
    """accelerate's BatchSamplerShard splits lerobot-train's batches between the ranks; each rank's sampler pairs
    the samples of its shard: over both, every sample is paired exactly once, with its own variation."""
    from accelerate.data_loader import BatchSamplerShard
    from torch.utils.data import BatchSampler

    agent_root, demo_root = door_datasets
    meta = LeRobotDatasetMetadata("mosaic/door_panda", root=agent_root)
    episode_of = np.repeat(np.arange(meta.total_episodes), meta.episodes["length"])
    episode_tasks = [t[0] for t in meta.episodes["tasks"]]
    order = list(np.random.default_rng(0).permutation(meta.total_frames)[:24])
    batches = BatchSampler(order, batch_size=4, drop_last=False)
    paired = []
    for rank in (0, 1):
        sampler = PairedDemoSampler("mosaic/door_sawyer", demo_root, IMAGE_KEY, 4, meta, threads=1, process_index=rank)
        for batch in BatchSamplerShard(batches, num_processes=2, process_index=rank):
            episodes = [int(episode_of[i]) for i in batch]
            tasks = [episode_tasks[e] for e in episodes]
            frames = sampler.sample(tasks, episodes)
            for i, frame in zip(batch, frames, strict=True):
                variation, _ = read_variation_rank(frame[0])
                assert variation_description(variation) == episode_tasks[episode_of[i]]
                paired.append(int(i))
        sampler.close()
    assert sorted(paired) == sorted(int(i) for i in order)  # each sample once, none missing


def test_decode_threads_are_shared_among_the_processes_of_a_machine(monkeypatch):
    """Two processes on two cores asked for 2 decode threads each get 1, their share of the cores."""
    monkeypatch.setattr(distributed, "usable_cpus", lambda: 2)
    monkeypatch.delenv("LOCAL_WORLD_SIZE", raising=False)
    assert distributed.demo_threads_per_process(2) == 2  # one process: what was asked
    monkeypatch.setenv("LOCAL_WORLD_SIZE", "2")
    assert distributed.demo_threads_per_process(2) == 1
    assert distributed.demo_threads_per_process(0) == 0  # synchronous decoding stays synchronous
    monkeypatch.setattr(distributed, "usable_cpus", lambda: 32)
    monkeypatch.setenv("LOCAL_WORLD_SIZE", "4")
    assert distributed.demo_threads_per_process(2) == 2


def test_outside_a_distributed_run_the_helpers_change_nothing():
    from tests.helpers.policy import small_config

    from mosaic_policy.mosaic.modeling_mosaic import MosaicPolicy

    policy = MosaicPolicy(small_config())
    before = {k: v.clone() for k, v in policy.state_dict().items()}
    state = torch.get_rng_state()
    distributed.average_batchnorm_statistics(policy)
    assert distributed.rank_random_generators() is False
    assert torch.equal(torch.get_rng_state(), state)
    assert all(torch.equal(before[k], v) for k, v in policy.state_dict().items())
