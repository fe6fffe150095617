"""A real `lerobot-train --policy.type=mosaic` run on tiny datasets, found through LeRobot's plugin discovery."""

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from conftest import IMAGE_KEY
from safetensors.torch import load_file

LEROBOT_TRAIN = str(Path(sys.executable).parent / "lerobot-train")
SMALL = [
    "--policy.train_obs_frames=3",
    "--policy.n_attention_heads=2",
    "--policy.embed_dim=32",
    "--policy.head_hidden_dim=32",
    "--policy.contrastive_dim=16",
    "--policy.contrastive_hidden_dim=32",
    "--policy.demo_loader_threads=1",
]


def _run(args, cwd):
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled", "OMP_NUM_THREADS": "1"}
    # Run outside the repository so that only the installed plugin can make `mosaic` known.
    return subprocess.run([LEROBOT_TRAIN, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


def _plugin_installed() -> bool:
    import importlib.metadata

    return any(d.metadata.get("Name") == "lerobot_policy_mosaic" for d in importlib.metadata.distributions())


pytestmark = pytest.mark.skipif(
    not _plugin_installed(), reason="pip install -e plugins/lerobot_policy_mosaic (README set-up) first"
)


def test_lerobot_train_runs_and_its_checkpoint_loads(door_datasets, tmp_path):
    agent_root, demo_root = door_datasets
    output = tmp_path / "run"
    result = _run(
        [
            "--policy.type=mosaic",
            "--dataset.repo_id=mosaic/door_panda",
            f"--dataset.root={agent_root}",
            "--policy.demo_repo_id=mosaic/door_sawyer",
            f"--policy.demo_root={demo_root}",
            "--policy.push_to_hub=false",
            "--policy.device=cpu",
            "--steps=2",
            "--batch_size=4",
            "--num_workers=0",
            "--save_freq=2",
            "--log_freq=1",
            f"--output_dir={output}",
            *SMALL,
        ],
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert "contrastive_loss" in result.stdout + result.stderr
    assert "[robosuite" not in result.stdout + result.stderr  # training does not load the simulator

    from lerobot.policies.factory import make_pre_post_processors
    from mosaic_policy.modeling_mosaic import MosaicPolicy

    checkpoint = output / "checkpoints" / "last" / "pretrained_model"
    policy = MosaicPolicy.from_pretrained(checkpoint)
    saved = load_file(checkpoint / "model.safetensors")
    state = policy.state_dict()
    assert saved.keys() == state.keys()
    assert all(torch.equal(saved[k], state[k]) for k in saved)
    assert int(policy.ema_step) == 2  # update() ran after each optimizer step
    assert policy.config.ema_total_steps is None  # the schedule's length is each run's --steps, never saved
    assert policy.config.demo_root is None  # no machine-local path in the policy's config.json
    assert str(demo_root) not in (checkpoint / "config.json").read_text()

    # The saved processors normalise with the dataset stats and unnormalise the action.
    preprocessor, postprocessor = make_pre_post_processors(policy.config, pretrained_path=str(checkpoint))
    policy.set_demo(torch.randint(0, 255, (20, 32, 56, 3), dtype=torch.uint8))
    batch = preprocessor({IMAGE_KEY: torch.rand(3, 32, 56), "observation.state": torch.randn(10), "task": "x"})
    action = postprocessor(policy.select_action(batch))
    assert action.shape == (1, 7) and torch.isfinite(action).all()


def test_lerobot_train_help_lists_mosaic_options(tmp_path):
    result = _run(["--policy.type=mosaic", "--help"], cwd=tmp_path)
    assert result.returncode == 0
    assert "--policy.demo_repo_id" in result.stdout
    assert "Softmax temperature dividing query-key dot products" in result.stdout


def test_lerobot_train_without_demo_dataset_fails_clearly(door_datasets, tmp_path):
    agent_root, _ = door_datasets
    result = _run(
        [
            "--policy.type=mosaic",
            "--dataset.repo_id=mosaic/door_panda",
            f"--dataset.root={agent_root}",
            "--policy.demo_repo_id=mosaic/door_sawyer",
            f"--policy.demo_root={tmp_path / 'missing'}",
            "--policy.push_to_hub=false",
            "--policy.device=cpu",
            "--steps=1",
            f"--output_dir={tmp_path / 'run'}",
            *SMALL,
        ],
        cwd=tmp_path,
    )
    assert result.returncode != 0
    assert "demonstrator dataset 'mosaic/door_sawyer' not found" in result.stdout + result.stderr


@pytest.mark.parametrize("resume", [False, True])
def test_fine_tuning_restarts_the_ema_schedule_and_resume_stretches_it(door_datasets, tmp_path, monkeypatch, resume):
    """A 1000-step checkpoint loaded to train again: fine-tuning starts at the base momentum, not at 1."""
    from conftest import small_config
    from lerobot.datasets import LeRobotDatasetMetadata

    from mosaic_policy.contrastive import ema_momentum
    from mosaic_policy.modeling_mosaic import MosaicPolicy

    agent_root, demo_root = door_datasets
    trained = MosaicPolicy(small_config())
    trained.ema_step.fill_(1000)
    trained.save_pretrained(tmp_path / "ckpt")
    argv = ["lerobot-train", "--policy.path=ckpt", "--steps=3000"] + (["--resume=true"] if resume else [])
    monkeypatch.setattr(sys, "argv", argv)
    config = small_config(demo_repo_id="mosaic/door_sawyer", demo_root=str(demo_root), demo_loader_threads=0)
    meta = LeRobotDatasetMetadata("mosaic/door_panda", root=agent_root)
    policy = MosaicPolicy.from_pretrained(tmp_path / "ckpt", config=config, dataset_meta=meta)
    assert policy.ema_total_steps == 3000
    assert int(policy.ema_step) == (1000 if resume else 0)
    momentum = ema_momentum(int(policy.ema_step), policy.ema_total_steps, config.ema_momentum)
    assert momentum < 1.0 and (momentum > config.ema_momentum if resume else momentum == config.ema_momentum)
    # the old behaviour: the schedule saved with the checkpoint had ended, momentum 1 froze the target
    assert ema_momentum(1000, 1000, config.ema_momentum) == 1.0
