"""One seed rule and one demonstration source for both front-ends: ``mosaic-eval --seed B`` and LeRobot's own
evaluation (``lerobot-eval --env.type=mosaic --seed B``, and its ``eval_policy`` called in-process) run the same
episodes, episode by episode: the same instances, the same demonstration frames, the same actions, the same final
gripper positions and successes. An untrained policy fails everywhere, so success alone would prove nothing."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from mosaic_data.constants import DEMO_RETRY_STRIDE, DEMO_SEED_OFFSET, MAX_EPISODES_PER_VARIATION, SEED_STRIDE_VARIATION
from mosaic_data.demos import DEMO_ATTEMPTS
from pipelines.evaluation.cli import main as mosaic_eval

from tests.helpers.evaluation import HEIGHT, WIDTH

BASE_SEED = 4242
VARIATIONS = (0, 2)
EPISODES = 2
STEPS = 12


def _demo_seeds(seed: int, variation: int) -> list[int]:
    """The demonstrator seeds the rule allows for episode seed ``seed``, worked out here from the constants."""
    first = seed + SEED_STRIDE_VARIATION * variation + DEMO_SEED_OFFSET
    return [first + DEMO_RETRY_STRIDE * retry for retry in range(DEMO_ATTEMPTS)]


def test_the_rule_gives_every_episode_its_own_instances():
    from pipelines.evaluation.seeds import episode_seed, episode_seeds

    seen: set[int] = set()
    for variation in range(4):
        for episode in (0, 1, MAX_EPISODES_PER_VARIATION - 1):
            seeds = episode_seeds(episode_seed(BASE_SEED, episode), variation)
            assert seeds.episode == BASE_SEED + episode, "what LeRobot resets episode e with"
            assert seeds.agent == BASE_SEED + episode + SEED_STRIDE_VARIATION * variation
            demos = _demo_seeds(seeds.episode, variation)
            assert seeds.demo == demos[0]
            instances = {seeds.agent, *demos}
            assert len(instances) == 1 + DEMO_ATTEMPTS and not instances & seen, "no instance is used twice"
            seen |= instances


@pytest.fixture(scope="module")
def mosaic_eval_run(tmp_path_factory, tiny_checkpoint):
    """mosaic-eval on door (one worker, in this process), with the demonstration each episode showed the policy
    and every action it took."""
    from pipelines.evaluation.agents import PolicyAgent

    shown: list[dict] = []
    start_episode, act = PolicyAgent.start_episode, PolicyAgent.act

    def spy_start(self, env, demo):
        shown.append({"demo": demo.frames.copy(), "demo_seed": demo.seed, "actions": []})
        return start_episode(self, env, demo)

    def spy_act(self, observation, env):
        step = act(self, observation, env)
        shown[-1]["actions"].append(step.action.copy())
        return step

    output = tmp_path_factory.mktemp("mosaic_eval") / "results.json"
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(PolicyAgent, "start_episode", spy_start)
        patch.setattr(PolicyAgent, "act", spy_act)
        code = mosaic_eval([
            f"--policy.path={tiny_checkpoint}", "--task", "door", "--variations", ",".join(map(str, VARIATIONS)),
            "--episodes-per-variation", str(EPISODES), "--max-steps", str(STEPS), "--seed", str(BASE_SEED),
            "--workers", "1", "--output", str(output), "--quiet",
        ])
    assert code == 0
    episodes = json.loads(output.read_text())["episodes"]
    assert [(e["variation"], e["episode"]) for e in episodes] == [(v, e) for v in VARIATIONS for e in range(EPISODES)]
    for episode, seen in zip(episodes, shown, strict=True):
        episode["shown_demo"], episode["actions"] = seen["demo"], np.stack(seen["actions"])
        assert seen["demo_seed"] == episode["demo_seed"]
    return episodes


def _lerobot_eval_in_process(checkpoint: Path) -> dict[int, list[dict]]:
    """LeRobot's own evaluation code on ``--env.type=mosaic``, built as lerobot-eval builds it: per variation, per
    episode, the seeds the environment was reset with and what the rollout saw and did."""
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.envs.factory import make_env, make_env_pre_post_processors
    from lerobot.policies.factory import make_policy, make_pre_post_processors
    from lerobot.scripts.lerobot_eval import eval_policy

    from pipelines.evaluation.agents import register_policy_types
    from pipelines.evaluation.lerobot_env import DemoConditionedEnv, MosaicEnv

    register_policy_types()
    env_config = MosaicEnv(
        task="door", variations=list(VARIATIONS), observation_height=HEIGHT, observation_width=WIDTH,
        episode_length=STEPS,
    )
    policy_config = PreTrainedConfig.from_pretrained(checkpoint)
    policy_config.pretrained_path = checkpoint
    policy = make_policy(cfg=policy_config, env_cfg=env_config).eval()
    preprocessor, postprocessor = make_pre_post_processors(
        policy_cfg=policy_config, pretrained_path=str(checkpoint),
        preprocessor_overrides={"device_processor": {"device": "cpu"}},
    )
    env_preprocessor, env_postprocessor = make_env_pre_post_processors(env_cfg=env_config, policy_cfg=policy_config)

    resets: list[dict] = []
    reset = DemoConditionedEnv.reset

    def spy_reset(self, *, seed=None, options=None):
        observation, info = reset(self, seed=seed, options=options)
        resets.append({"seed_given": seed, "seed": info["seed"], "demo_seed": info["demo_seed"]})
        return observation, info

    envs = make_env(env_config, n_envs=1)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # as mosaic-eval's workers: the same floating-point sums
    by_variation: dict[int, list[dict]] = {}
    try:
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(DemoConditionedEnv, "reset", spy_reset)
            for variation, env in envs["door"].items():
                resets.clear()
                with torch.no_grad():
                    info = eval_policy(
                        env, policy, env_preprocessor, env_postprocessor, preprocessor, postprocessor,
                        n_episodes=EPISODES, return_episode_data=True, start_seed=BASE_SEED,
                    )
                assert len(resets) == EPISODES, "one reset per episode: no autoreset makes a thrown-away demonstration"
                data = info["episodes"]
                episodes = []
                for index, (result, seeds) in enumerate(zip(info["per_episode"], resets, strict=True)):
                    mask = data["episode_index"] == index
                    episodes.append({
                        **seeds, "lerobot_seed": result["seed"], "success": bool(result["success"]),
                        "actions": data["action"][mask][:-1].numpy(),  # the last row pads the final observation
                        "states": data["observation.state"][mask].numpy(),
                        "demo": data["observation.demo"][mask][0].numpy(),
                    })
                by_variation[variation] = episodes
    finally:
        torch.set_num_threads(threads)
        for env in envs["door"].values():
            env.close()
    return by_variation


def test_mosaic_eval_and_lerobot_eval_give_the_same_episodes(mosaic_eval_run, tiny_checkpoint):
    lerobot = _lerobot_eval_in_process(tiny_checkpoint)
    assert sorted(lerobot) == list(VARIATIONS)
    for ours in mosaic_eval_run:
        variation, index = ours["variation"], ours["episode"]
        theirs = lerobot[variation][index]
        episode_seed = BASE_SEED + index
        assert theirs["seed_given"] == theirs["lerobot_seed"] == episode_seed, "LeRobot resets episode e with --seed + e"
        assert ours["seed"] == theirs["seed"] == episode_seed + SEED_STRIDE_VARIATION * variation
        assert ours["demo_seed"] == theirs["demo_seed"] and ours["demo_seed"] in _demo_seeds(episode_seed, variation)

        assert theirs["demo"].shape == ours["shown_demo"].shape == (4, HEIGHT, WIDTH, 3)
        assert np.array_equal(theirs["demo"], ours["shown_demo"]), "the same demonstration frames"
        assert ours["steps"] == len(theirs["actions"]) == STEPS
        np.testing.assert_array_equal(theirs["actions"], ours["actions"].astype(np.float32), err_msg="the same actions")
        np.testing.assert_allclose(theirs["states"][-1][:3], ours["final_position"], rtol=0, atol=2e-6)
        assert ours["success"] == theirs["success"]

    finals = [tuple(e["final_position"]) for e in mosaic_eval_run]
    assert len(set(finals)) == len(finals), "every episode ends elsewhere: the comparison is not of constants"
    first_frames = [e["shown_demo"][0].tobytes() for e in mosaic_eval_run]
    assert len(set(first_frames)) == len(first_frames), "every episode has its own demonstration"


def test_the_lerobot_eval_command_runs_the_same_episodes(tmp_path, mosaic_eval_run, tiny_checkpoint):
    lerobot_eval = Path(sys.executable).parent / "lerobot-eval"
    environment = os.environ | {
        "MUJOCO_GL": "egl", "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled", "OMP_NUM_THREADS": "1",
    }
    variations = ",".join(map(str, VARIATIONS))
    result = subprocess.run(
        [
            str(lerobot_eval), f"--policy.path={tiny_checkpoint}", "--env.type=mosaic", "--env.task=door",
            f"--env.variations=[{variations}]", f"--env.observation_height={HEIGHT}", f"--env.observation_width={WIDTH}",
            f"--env.episode_length={STEPS}", f"--eval.n_episodes={EPISODES}", "--eval.batch_size=1",
            f"--seed={BASE_SEED}", f"--output_dir={tmp_path / 'eval'}",
        ],
        capture_output=True, text=True, env=environment, timeout=600,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    logged = re.findall(
        r"door variation (\d+), episode seed (\d+): agent instance (\d+), demonstration seed (\d+)",
        result.stdout + result.stderr,
    )
    assert [tuple(map(int, line)) for line in logged] == [
        (e["variation"], BASE_SEED + e["episode"], e["seed"], e["demo_seed"]) for e in mosaic_eval_run
    ]
    info = json.loads((tmp_path / "eval" / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == len(mosaic_eval_run)
    successes = {task["task_id"]: task["metrics"]["successes"] for task in info["per_task"]}
    assert successes == {
        variation: [e["success"] for e in mosaic_eval_run if e["variation"] == variation] for variation in VARIATIONS
    }
