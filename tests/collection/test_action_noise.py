"""DART-style noise injection (``--action-noise``): the simulator executes perturbed actions, the dataset records the
expert's clean ones; deterministic per seed; zero noise is no noise; the dataset's sidecar says how it was made."""

from __future__ import annotations

import json

import numpy as np
import pytest
from tests.helpers.cli_errors import one_line_error

from mosaic_data import rollout
from mosaic_data.action_noise import ActionNoise, parse_action_noise
from mosaic_data.collection.metadata import read_sidecar
from mosaic_data.collection.plan import CollectionSettings
from mosaic_data.envs import ACTION_HIGH, ACTION_LOW

SEED = 3
NOISE = ActionNoise(0.005, 0.02)
ARGS = ["collect", "--task", "door", "--robot", "panda", "--variations", "0", "--episodes", "1", "--workers", "1",
        "--image-size", "32x56", "--quiet"]


def _run(env, noise: ActionNoise | None, seed: int = SEED):
    """``run_expert_episode`` with what the expert returned and what the environment executed, step by step."""
    returned, executed = [], []
    make_expert = rollout.make_expert

    def watched_expert(*args, **kwargs):
        expert = make_expert(*args, **kwargs)
        act = expert.act

        def watched_act(*act_args, **act_kwargs):
            action = act(*act_args, **act_kwargs)
            returned.append(action.copy())
            return action

        expert.act = watched_act
        return expert

    step = env.step

    def watched_step(action):
        executed.append(np.array(action, dtype=np.float64, copy=True))
        return step(action)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(rollout, "make_expert", watched_expert)
        patch.setattr(env, "step", watched_step)
        episode = rollout.run_expert_episode(env, seed, action_noise=noise)
    return episode, np.array(returned), np.array(executed)


@pytest.fixture(scope="module")
def door_env():
    from mosaic_data.tasks import make_task_env

    env = make_task_env("door", 0, "panda")
    yield env
    env.close()


@pytest.fixture(scope="module")
def episodes(door_env):
    """The same door episode without noise, twice with the default noise, and with all-zero noise."""
    return {
        "clean": _run(door_env, None),
        "noisy": _run(door_env, NOISE),
        "noisy_again": _run(door_env, NOISE),
        "zero": _run(door_env, ActionNoise(0.0, 0.0)),
    }


def test_the_dataset_gets_the_clean_action_the_simulator_a_perturbed_one(episodes, door_env):
    episode, returned, executed = episodes["noisy"]
    assert episode.success and episode.success == door_env.check_success()  # the env's own verdict
    recorded = np.array(episode.actions)
    assert recorded.dtype == np.float32 and np.array_equal(recorded, returned)  # exactly what the expert returned
    assert len(executed) == len(returned) == episode.length
    position_error = np.linalg.norm(executed[:, :3] - returned[:, :3], axis=1)
    assert (position_error > 0).all() and 0.002 < position_error.mean() < 0.02  # ~ sqrt(3) * 5 mm
    from scipy.spatial.transform import Rotation

    turn = (Rotation.from_rotvec(executed[:, 3:6]) * Rotation.from_rotvec(returned[:, 3:6].astype(np.float64)).inv()).magnitude()
    assert (turn > 0).all() and 0.01 < turn.mean() < 0.08  # ~ sqrt(3) * 0.02 rad
    assert np.array_equal(executed[:, 6], returned[:, 6])  # never the gripper
    assert (executed >= ACTION_LOW).all() and (executed <= ACTION_HIGH).all()  # in the action box
    clean, clean_returned, clean_executed = episodes["clean"]
    assert clean.success and np.array_equal(clean_executed, clean_returned)  # without noise: executed as returned
    assert not np.array_equal(np.array(clean.states), np.array(episode.states)[: clean.length])  # it moved elsewhere


def test_same_seed_and_noise_give_the_same_episode(episodes, door_env):
    (first, _, executed), (second, _, executed_again) = episodes["noisy"], episodes["noisy_again"]
    assert first.length == second.length and first.success == second.success
    assert np.array_equal(np.array(first.states), np.array(second.states))
    assert np.array_equal(np.array(first.actions), np.array(second.actions))
    assert np.array_equal(executed, executed_again)
    other_seed = rollout.run_expert_episode(door_env, SEED + 1, action_noise=NOISE)
    assert not np.array_equal(np.array(other_seed.actions)[:5], np.array(first.actions)[:5])


def test_zero_noise_is_no_noise(episodes):
    (clean, _, clean_executed), (zero, _, zero_executed) = episodes["clean"], episodes["zero"]
    assert zero.length == clean.length and zero.success == clean.success
    assert np.array_equal(np.array(zero.states), np.array(clean.states))
    assert np.array_equal(np.array(zero.actions), np.array(clean.actions))
    assert np.array_equal(zero_executed, clean_executed)


def test_the_option_parses_and_zero_means_none():
    assert parse_action_noise("0.005") == ActionNoise(0.005, 0.02)  # the rotation follows the position
    assert parse_action_noise(" 0.01 , 0 ") == ActionNoise(0.01, 0.0)
    assert parse_action_noise("0") is None and parse_action_noise("0,0") is None
    base = dict(task="door", robot="panda", variations=(0,), episodes_per_variation=1, base_seed=0, image_height=32, image_width=56)
    assert "action_noise" not in CollectionSettings(**base).to_json()  # datasets without noise: settings as before
    assert CollectionSettings(**base, action_noise=ActionNoise(0.0, 0.0)) == CollectionSettings(**base)
    noisy = CollectionSettings(**base, action_noise=NOISE)
    assert CollectionSettings.from_json(json.loads(json.dumps(noisy.to_json()))) == noisy
    with pytest.raises(ValueError):
        ActionNoise(-0.001, 0.0)


def test_a_noisy_collection_records_its_noise_and_loads(tmp_path, cli, capsys):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from mosaic_data.collection.validate import validate_dataset

    output = tmp_path / "out"
    assert cli(*ARGS, "--action-noise", "0.005", "--output-dir", str(output)) == 0
    root = output / "mosaic" / "door_panda"
    sidecar = read_sidecar(root)
    noise = sidecar["sources"][0]["settings"]["action_noise"]
    assert (noise["position_std_m"], noise["rotation_std_rad"]) == (0.005, 0.02)
    assert "records the expert action" in noise["rule"]
    _, problems = validate_dataset(root)
    assert problems == []
    dataset = LeRobotDataset("mosaic/door_panda", root=root)
    assert dataset.num_episodes == 1
    (record,) = sidecar["episodes"]

    # The sidecar regenerates the episode: its seed and noise give the expert's clean actions the dataset holds.
    from mosaic_data.tasks import make_task_env

    env = make_task_env("door", 0, "panda", image_height=32, image_width=56)
    try:
        episode = rollout.run_expert_episode(env, record["seed"], action_noise=ActionNoise.from_json(noise))
    finally:
        env.close()
    stored = np.array([np.asarray(action) for action in dataset.hf_dataset["action"]], dtype=np.float32)
    assert episode.length == record["length"] == len(stored)
    assert np.array_equal(stored, np.array(episode.actions))

    capsys.readouterr()
    # The same options again: complete, left alone. Other noise: other settings, refused like any other change.
    assert cli(*ARGS, "--action-noise", "0.005,0.02", "--output-dir", str(output)) == 0
    assert "complete, left alone" in capsys.readouterr().out
    assert cli(*ARGS, "--output-dir", str(output)) == 2
    one_line_error(capsys, "other settings", "action_noise 0.005 m,0.02 rad instead of none", "--overwrite")
    assert cli(*ARGS, "--action-noise", "0.01", "--output-dir", str(output)) == 2
    one_line_error(capsys, "other settings", "action_noise 0.005 m,0.02 rad instead of 0.01 m,0.04 rad")


def test_an_unfinished_run_with_other_noise_is_not_resumed_with_this_one(tmp_path, cli, capsys):
    from mosaic_data.collection.collect import CollectRequest, plan_jobs, source_of

    output = tmp_path / "out"
    (job,) = plan_jobs(CollectRequest("door", ["panda"], [0], 1, output_dir=output, image_height=32, image_width=56, action_noise=NOISE))
    job.staging_dir.mkdir(parents=True)
    (job.staging_dir / "plan.json").write_text(json.dumps(source_of(job)))
    assert cli(*ARGS, "--output-dir", str(output)) == 2
    one_line_error(capsys, "unfinished collection", "action_noise 0.005 m,0.02 rad instead of none")


@pytest.mark.parametrize(
    ("value", "words"),
    [
        ("abc", ["--action-noise", "POS_STD_M[,ROT_STD_RAD]", "'abc'"]),
        ("-0.01", ["--action-noise", "negative"]),
        ("0.005,-1", ["--action-noise", "negative"]),
        ("nan", ["--action-noise", "finite"]),
        ("0.005,0.02,1", ["--action-noise", "POS_STD_M"]),
        ("0.005,", ["--action-noise", "POS_STD_M"]),
        ("5", ["--action-noise", "at most 0.05 m", "millimetres"]),
        ("0.01,2", ["--action-noise", "at most 0.5 rad"]),
    ],
)
def test_a_bad_noise_value_is_one_line_and_writes_nothing(tmp_path, cli, capsys, value, words):
    output = tmp_path / "out"
    assert cli(*ARGS, "--action-noise", value, "--output-dir", str(output)) == 2
    one_line_error(capsys, *words)
    assert not output.exists()
