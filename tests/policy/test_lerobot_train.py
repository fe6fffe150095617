"""A real `lerobot-train --policy.type=mosaic` run on tiny datasets, found through LeRobot's plugin discovery."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from tests.helpers.policy import IMAGE_KEY, lerobot_train_help

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
            "--policy.variation_loss_weight=1",  # this project's option: LeRobot's batches carry the task strings
            "--policy.hand_relative_targets=true",  # fitted to the dataset lerobot-train hands the policy
            *SMALL,
        ],
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert "contrastive_loss" in result.stdout + result.stderr
    assert "variation_loss" in result.stdout + result.stderr
    assert "[robosuite" not in result.stdout + result.stderr  # training does not load the simulator

    from lerobot.policies.factory import make_pre_post_processors
    from mosaic_policy.mosaic.modeling_mosaic import MosaicPolicy

    checkpoint = output / "checkpoints" / "last" / "pretrained_model"
    policy = MosaicPolicy.from_pretrained(checkpoint)
    saved = load_file(checkpoint / "model.safetensors")
    state = policy.state_dict()
    assert saved.keys() == state.keys()
    assert any(key.startswith("model.variation_projector.") for key in saved)
    assert saved["hand_relative.offset_max"].gt(saved["hand_relative.offset_min"]).all()  # measured, not the default
    assert not torch.equal(saved["hand_relative.state_std"], torch.ones(3))
    assert all(torch.equal(saved[k], state[k]) for k in saved)
    assert int(policy.ema_step) == 2  # update() ran after each optimizer step
    train_config = json.loads((output / "checkpoints" / "last" / "pretrained_model" / "train_config.json").read_text())
    assert train_config["scheduler"]["type"] == "run_progress"  # the preset that tells the policy the run's length
    assert policy.config.ema_total_steps is None  # the schedule's length is each run's --steps, never saved
    assert policy.config.demo_root is None  # no machine-local path in the policy's config.json
    assert str(demo_root) not in (checkpoint / "config.json").read_text()

    # The saved processors normalise with the dataset stats and unnormalise the action.
    preprocessor, postprocessor = make_pre_post_processors(policy.config, pretrained_path=str(checkpoint))
    policy.set_demo(torch.randint(0, 255, (20, 32, 56, 3), dtype=torch.uint8))
    batch = preprocessor({IMAGE_KEY: torch.rand(3, 32, 56), "observation.state": torch.randn(10), "task": "x"})
    action = postprocessor(policy.select_action(batch))
    assert action.shape == (1, 7) and torch.isfinite(action).all()


def test_lerobot_train_help_lists_mosaic_options():
    help_text = lerobot_train_help("mosaic")
    assert "--policy.demo_repo_id" in help_text
    assert "Softmax temperature dividing query-key dot products" in help_text
    assert "--policy.vision_backbone" in help_text and "4 strided convs" in help_text
    assert "--policy.temporal_ensemble_coeff" in help_text and "--policy.state_components" in help_text


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


def test_the_ema_schedule_follows_the_run_lerobot_train_reports_fine_tuning_restarts_it_resume_continues_it():
    """lerobot-train tells the policy's scheduler preset its --steps; the EMA momentum reads the run's progress from
    it (no command line parsing). A fine-tuning run builds a new scheduler: the schedule restarts at the base
    momentum instead of the finished schedule's 1 (which would freeze the target encoder); --resume restores the
    scheduler's step count and the schedule ends at the new --steps."""
    from tests.helpers.policy import small_config

    from mosaic_policy.common.run_progress import RunProgressSchedulerConfig, run_progress
    from mosaic_policy.mosaic.contrastive import ema_momentum
    from mosaic_policy.mosaic.modeling_mosaic import MosaicPolicy

    config = small_config()
    policy = MosaicPolicy(config)
    preset = config.get_scheduler_preset()
    assert isinstance(preset, RunProgressSchedulerConfig) and preset.type == "run_progress"
    optimizer = torch.optim.Adam(policy.get_optim_params(), lr=config.optimizer_lr)
    first_run = preset.build(optimizer, 1000)
    for _ in range(1000):
        optimizer.step()
        first_run.step()
    assert run_progress() == (1000, 1000)
    assert policy.ema_schedule() == (999, 1000)
    assert optimizer.param_groups[0]["lr"] == config.optimizer_lr  # the preset keeps the learning rate constant

    fine_tuning = preset.build(torch.optim.Adam(policy.get_optim_params()), 3000)
    assert policy.ema_schedule() == (0, 3000)
    assert ema_momentum(*policy.ema_schedule(), config.ema_momentum) == config.ema_momentum

    resumed = preset.build(torch.optim.Adam(policy.get_optim_params()), 3000)
    resumed.load_state_dict(first_run.state_dict())  # what lerobot-train's load_training_state does
    assert policy.ema_schedule() == (999, 3000)
    assert config.ema_momentum < ema_momentum(*policy.ema_schedule(), config.ema_momentum) < 1.0
    del fine_tuning, resumed, first_run


def test_the_cosine_schedule_ends_at_its_final_ratio_on_the_runs_last_step_and_resume_keeps_the_new_length():
    """`--policy.lr_schedule=cosine`: the rate falls from `optimizer_lr` to `lr_final_ratio` of it at the run's
    `--steps` (half-way: the mean of the two), and stays there; `--resume` to more steps stretches the rest of the
    decay to the new end."""
    from tests.helpers.policy import small_config

    config = small_config()
    config.lr_schedule, config.lr_final_ratio = "cosine", 0.1
    parameter = torch.nn.Parameter(torch.zeros(1))
    optimizer = torch.optim.Adam([parameter], lr=config.optimizer_lr)
    scheduler = config.get_scheduler_preset().build(optimizer, 100)
    rates = [optimizer.param_groups[0]["lr"]]
    for _ in range(120):
        optimizer.step()
        scheduler.step()
        rates.append(optimizer.param_groups[0]["lr"])
    assert rates[0] == pytest.approx(config.optimizer_lr)
    assert rates[50] == pytest.approx(0.55 * config.optimizer_lr)
    assert rates[100] == rates[120] == pytest.approx(0.1 * config.optimizer_lr)
    assert all(later <= earlier for earlier, later in zip(rates, rates[1:]))

    resumed_optimizer = torch.optim.Adam([parameter], lr=config.optimizer_lr)
    resumed = config.get_scheduler_preset().build(resumed_optimizer, 200)
    halfway_optimizer = torch.optim.Adam([parameter], lr=config.optimizer_lr)
    halfway = config.get_scheduler_preset().build(halfway_optimizer, 100)
    for _ in range(50):
        halfway_optimizer.step()
        halfway.step()
    resumed.load_state_dict(halfway.state_dict())
    assert resumed.total_steps == 200 and resumed.lr_factor(100) == pytest.approx(0.55)
