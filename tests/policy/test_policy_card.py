"""What a pushed MOSAIC policy carries: a card that says how to install the plugin, what the demonstration input
is and how to evaluate it in the suite; a config.json without machine-local paths, that still loads."""

import json
import os
import shutil
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch
from tests.helpers.policy import HEIGHT, IMAGE_KEY, WIDTH, small_config

from mosaic_policy.common.model_card import eval_task_option
from mosaic_policy.mosaic.modeling_mosaic import MosaicPolicy


def _strings(value):
    if isinstance(value, str):
        yield value
    elif isinstance(value, dict):
        for item in value.values():
            yield from _strings(item)
    elif isinstance(value, list):
        for item in value:
            yield from _strings(item)


@pytest.fixture()
def trained_here(tmp_path):
    """A policy configured as lerobot-train configures it on this machine: a local demonstrator folder."""
    demo_root = tmp_path / "datasets" / "mosaic" / "door_sawyer"
    config = small_config(demo_repo_id="mosaic/door_sawyer", demo_root=str(demo_root), repo_id="someone/mosaic_door")
    torch.manual_seed(0)
    return MosaicPolicy(config), demo_root


def test_saved_config_holds_no_machine_local_path(trained_here, tmp_path):
    policy, demo_root = trained_here
    policy.save_pretrained(tmp_path / "ckpt")
    saved = json.loads((tmp_path / "ckpt" / "config.json").read_text())
    assert saved["demo_root"] is None
    assert saved["demo_repo_id"] == "mosaic/door_sawyer"
    assert not [s for s in _strings(saved) if os.path.isabs(s) or str(tmp_path) in s]
    assert policy.config.demo_root == str(demo_root)  # the running policy keeps its own setting


def test_a_saved_policy_loads_and_acts_for_evaluation(trained_here, tmp_path):
    policy, _ = trained_here
    policy.eval()
    policy.save_pretrained(tmp_path / "ckpt")
    loaded = MosaicPolicy.from_pretrained(tmp_path / "ckpt").eval()
    assert loaded.config.demo_root is None and loaded.config.demo_repo_id == "mosaic/door_sawyer"
    demo = torch.randint(0, 255, (20, HEIGHT, WIDTH, 3), dtype=torch.uint8)
    frame = {IMAGE_KEY: torch.rand(1, 3, HEIGHT, WIDTH), "observation.state": torch.randn(1, 10)}
    actions = []
    for model in (policy, loaded):
        model.reset()
        model.set_demo(demo)
        actions.append(model.select_action(frame))
    torch.testing.assert_close(actions[0], actions[1])


def test_the_card_says_how_to_install_feed_and_evaluate_the_policy(trained_here, door_datasets):
    from lerobot.datasets import LeRobotDatasetMetadata

    policy, _ = trained_here
    agent_root, _ = door_datasets
    meta = LeRobotDatasetMetadata("mosaic/door_panda", root=agent_root)
    card = str(policy.generate_model_card("mosaic/door_panda", "mosaic", None, None, dataset_meta=meta))
    assert "pip install" in card and "plugins/lerobot_policy_mosaic" in card
    assert "mosaic-eval --policy.path=someone/mosaic_door" in card
    assert "lerobot-eval --policy.path=someone/mosaic_door --env.type=mosaic" in card
    assert "set_demo" in card and "observation.demo" in card and f"{HEIGHT}x{WIDTH}" in card
    assert "mosaic/door_sawyer" in card and "mosaic/door_panda" in card
    assert "lerobot-rollout" not in card and "--robot.type" not in card
    assert str(agent_root) not in card


def test_eval_commands_name_the_task_of_the_training_variations():
    from mosaic_data.tasks.spec import VARIATIONS

    door = [v.description for v in VARIATIONS["door"]]
    drawer = [v.description for v in VARIATIONS["drawer"]]
    assert eval_task_option(door[:2]) == "door"
    assert eval_task_option(door + drawer) == "all"
    assert eval_task_option(["open door 0 left"]) == "<task>"
    assert eval_task_option([]) == "<task>"


def test_push_model_to_hub_uploads_the_mosaic_card_and_a_portable_config(trained_here, tmp_path, monkeypatch):
    """LeRobot's own push path, with the Hub replaced by a folder."""
    import lerobot.policies.pretrained as pretrained

    uploaded = tmp_path / "hub"

    class FolderHub:
        def create_repo(self, repo_id, private=None, exist_ok=False):
            return SimpleNamespace(repo_id=repo_id)

        def upload_folder(self, repo_id, folder_path, **kwargs):
            shutil.copytree(folder_path, uploaded)
            return SimpleNamespace(repo_url=SimpleNamespace(url=f"https://huggingface.co/{repo_id}"))

    monkeypatch.setattr(pretrained, "HfApi", FolderHub)
    policy, _ = trained_here
    cfg = SimpleNamespace(
        dataset=SimpleNamespace(repo_id="mosaic/door_panda"),
        steps=20000, batch_size=30, seed=1000, optimizer=SimpleNamespace(type="adam", lr=5e-4),
        save_pretrained=lambda path: (Path(path) / "train_config.json").write_text("{}"),
    )
    policy.push_model_to_hub(cfg)
    card = (uploaded / "README.md").read_text()
    assert "lerobot_policy_mosaic" in card and "mosaic-eval" in card and "lerobot-rollout" not in card
    assert "| Batch size | 30 |" in card
    assert json.loads((uploaded / "config.json").read_text())["demo_root"] is None
