"""The suite as gymnasium environments: async vector envs with gymnasium's defaults, episode length from
gymnasium's TimeLimit, a bounded ``agent_pos``, ``reset(options={"variation": k})``, and gymnasium's own checker.
Real simulator, headless EGL rendering, small images."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import warnings

import gymnasium
import numpy as np
import pytest

import mosaic_data  # noqa: F401  (registers the environments)
from mosaic_data.envs import GRIP_SITE_REACH, MosaicGymEnv, grip_site_reach, gym_id
from mosaic_data.experts import make_expert
from mosaic_data.tasks import TASK_NAMES, get_task_class
from mosaic_data.tasks.spec import TASK_SPECS

HEIGHT, WIDTH = 24, 32


def _run_python(code: str, timeout_s: float) -> str:
    """Run ``code`` in a fresh interpreter and return its stdout; fail (instead of hanging the suite) if it runs
    past ``timeout_s``, killing its whole process group (vector-env workers included)."""
    environment = os.environ | {"MUJOCO_GL": "egl", "HF_HUB_OFFLINE": "1"}
    process = subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(code)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env=environment, start_new_session=True,
    )
    try:
        stdout, stderr = process.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        process.communicate()
        pytest.fail(f"the script hung for more than {timeout_s} s")
    assert process.returncode == 0, stderr[-3000:]
    return stdout


def _hold_still(observation_pos: np.ndarray) -> np.ndarray:
    """An action that keeps the grip site where it is, pointing down, gripper open (one env's agent_pos)."""
    return np.concatenate([observation_pos[:3], [0.0, 0.0, 0.0, -1.0]]).astype(np.float32)


# ---------------------------------------------------------------------------------------------- 1. async vector envs
def test_async_make_vec_steps_two_envs_with_gymnasium_defaults():
    """The parent made one env for the spaces (with its GL context) and then forked: the workers hung forever."""
    stdout = _run_python(
        f"""
        import gymnasium, numpy as np, mosaic_data
        envs = gymnasium.make_vec("mosaic/NutAssembly-v0", num_envs=2, vectorization_mode="async",
                                  image_height={HEIGHT}, image_width={WIDTH})
        obs, info = envs.reset(seed=[1, 2])
        assert obs["pixels"]["agentview"].shape == (2, {HEIGHT}, {WIDTH}, 3), obs["pixels"]["agentview"].shape
        assert obs["pixels"]["agentview"].std() > 5, "rendered frames, not blank ones"
        assert list(info["seed"]) == [1, 2] and not np.allclose(obs["agent_pos"][0], obs["agent_pos"][1])
        start = obs["agent_pos"].copy()
        actions = np.concatenate([start[:, :3] + [0.0, 0.0, 0.03], np.zeros((2, 3)), -np.ones((2, 1))], axis=1)
        for _ in range(4):
            obs, reward, terminated, truncated, info = envs.step(actions.astype(np.float32))
        lifted = obs["agent_pos"][:, 2] - start[:, 2]
        assert np.all(lifted > 0.005), lifted
        assert envs.observation_space.contains(obs)
        envs.close()
        print("stepped", lifted)
        """,
        timeout_s=300,
    )
    assert "stepped" in stdout


def test_async_make_vec_after_the_parent_rendered_fails_fast_naming_spawn():
    """A fork after the parent rendered cannot work (EGL's threads do not survive it): a one-line error naming the
    spawn context instead of a hang, and the spawn context it names works."""
    stdout = _run_python(
        f"""
        import gymnasium, mosaic_data
        kwargs = dict(image_height={HEIGHT}, image_width={WIDTH}, observe_image=False)
        parent = gymnasium.make("mosaic/Door-v0", **kwargs)
        parent.reset(seed=0)
        parent.render()
        envs = gymnasium.make_vec("mosaic/Door-v0", num_envs=2, vectorization_mode="async", **kwargs)
        try:
            envs.reset(seed=0)
        except RuntimeError as error:
            message = str(error)
            assert "\\n" not in message and "vector_kwargs={{'context': 'spawn'}}" in message, message
            print("fails fast")
        envs.close(terminate=True)
        envs = gymnasium.make_vec("mosaic/Door-v0", num_envs=2, vectorization_mode="async",
                                  vector_kwargs={{"context": "spawn"}}, **kwargs)
        obs, _ = envs.reset(seed=0)
        envs.step(envs.action_space.sample())
        envs.close()
        parent.close()
        print("spawn works")
        """,
        timeout_s=300,
    )
    assert "fails fast" in stdout and "spawn works" in stdout


def test_making_an_env_builds_no_scene():
    """What makes async vector envs work: the simulator and its GL context come at the first reset."""
    env = gymnasium.make("mosaic/Door-v0", image_height=HEIGHT, image_width=WIDTH)
    assert env.unwrapped._task_env is None
    env.close()
    assert env.unwrapped._task_env is None


# ---------------------------------------------------------------------------------------------- 2. TimeLimit
def test_registered_with_the_task_horizon_as_max_episode_steps():
    for task in TASK_NAMES:
        assert gymnasium.spec(gym_id(task)).max_episode_steps == TASK_SPECS[task].horizon_steps, task
    env = gymnasium.make("mosaic/Door-v0", observe_image=False)
    assert isinstance(env, gymnasium.wrappers.TimeLimit) and env.get_wrapper_attr("_max_episode_steps") == 130
    env.close()


def test_truncation_comes_from_time_limit():
    env = gymnasium.make("mosaic/Door-v0", observe_image=False, max_episode_steps=3)
    try:
        obs, _ = env.reset(seed=1)
        flags = [env.step(_hold_still(obs["agent_pos"]))[2:4] for _ in range(3)]
        assert flags == [(False, False), (False, False), (False, True)]
    finally:
        env.close()
    bare = MosaicGymEnv("door", observe_image=False, horizon=2)  # no TimeLimit: the env itself never truncates
    try:
        obs, _ = bare.reset(seed=1)
        assert [bare.step(_hold_still(obs["agent_pos"]))[3] for _ in range(3)] == [False, False, False]
    finally:
        bare.close()


def test_make_with_horizon_names_max_episode_steps():
    with pytest.raises(ValueError, match=r"pass max_episode_steps=5 instead of horizon"):
        gymnasium.make("mosaic/Door-v0", horizon=5)


def test_lerobot_env_is_truncated_by_time_limit_and_builds_no_scene_until_reset():
    from lerobot.envs.utils import FreezeAfterEpisodeEnd

    from pipelines.evaluation.lerobot_env import DemoConditionedEnv, make_demo_conditioned_env

    env = make_demo_conditioned_env("door", 1, "panda", "sawyer", HEIGHT, WIDTH, 4, episode_length=3)
    assert isinstance(env, FreezeAfterEpisodeEnd) and isinstance(env.env, DemoConditionedEnv)
    assert isinstance(env.env.env, gymnasium.wrappers.TimeLimit)
    assert env.get_wrapper_attr("_max_episode_steps") == 3  # what LeRobot's evaluation loop reads
    assert env.unwrapped._task_env is None and env.env._source is None
    env.close()


# ---------------------------------------------------------------------------------------------- 3. bounded agent_pos
@pytest.mark.parametrize("robot", ["panda", "sawyer"])
def test_agent_pos_is_bounded_by_the_robots_reach_and_holds_expert_episodes(robot):
    env = gymnasium.make("mosaic/Door-v0", robot=robot, observe_image=False)
    try:
        space = env.observation_space["agent_pos"]
        assert np.all(np.isfinite(space.low)) and np.all(np.isfinite(space.high))
        assert np.all(space.high[:3] - space.low[:3] < 3.0), "a box around the arm's reach, not a placeholder"
        obs, _ = env.reset(seed=0)
        expert = make_expert(env)
        observations = [obs]
        terminated = truncated = False
        while not (terminated or truncated):
            obs, _, terminated, truncated, _ = env.step(expert.act(obs, env))
            observations.append(obs)
        assert terminated, "the expert succeeds (a real episode)"
        outside = [i for i, o in enumerate(observations) if not env.observation_space.contains(o)]
        assert not outside, f"observations {outside} outside observation_space"

        task_env = env.unwrapped.task_env
        pivot, reach = grip_site_reach(task_env.sim.model._model, task_env.robot.eef_site_id["right"])
        centre, stated = GRIP_SITE_REACH[robot]
        np.testing.assert_allclose(pivot, centre, atol=1e-6)
        assert reach <= stated <= reach + 0.01, (reach, stated)
    finally:
        env.close()
    # the robot's base, hence its pivot, sits at the table's edge: one table size for all tasks keeps one bound valid
    assert len({get_task_class(task).table_full_size for task in TASK_NAMES}) == 1


# ---------------------------------------------------------------------------------------------- 4. variation option
def test_reset_option_switches_the_variation_in_the_same_env():
    env = gymnasium.make("mosaic/Door-v0", variation=0, observe_image=False)
    try:
        obs, info = env.reset(seed=3, options={"variation": 2})
        assert info["variation"] == 2 and info["task"] == TASK_SPECS["door"].variations[2].description
        assert env.unwrapped.variation == 2 and env.unwrapped.task_env.variation_index == 2
        expert = make_expert(env)  # the env's own variation: 2
        assert expert.variation.index == 2
        terminated = truncated = False
        while not (terminated or truncated):
            obs, reward, terminated, truncated, info = env.step(expert.act(obs, env))
        assert terminated and reward == 1.0 and info["variation"] == 2, "success is judged on variation 2's goal"

        _, info = env.reset(seed=4)
        assert info["variation"] == 2, "the switch lasts until the next one"
        one_line = r"^unknown variation 4 for task 'door': choose an integer in 0\.\.3 [^\n]*$"
        with pytest.raises(ValueError, match=one_line):
            env.reset(options={"variation": 4})
        with pytest.raises(ValueError, match=r"unknown reset option 'variaton': did you mean 'variation'\?"):
            env.reset(options={"variaton": 1})
        _, info = env.reset(seed=4, options={"lerobot_new_rollout": True})  # other wrappers' options pass through
        assert info["variation"] == 2, "a rejected option changes nothing"
        _, info = env.reset(seed=4, options={"variation": np.int64(1)})
        assert info["variation"] == 1
    finally:
        env.close()


def test_lerobot_env_demonstrates_the_variation_chosen_at_reset():
    from mosaic_data.constants import DEMO_RETRY_STRIDE
    from mosaic_data.demos import DEMO_ATTEMPTS
    from pipelines.evaluation.lerobot_env import make_demo_conditioned_env
    from pipelines.evaluation.seeds import episode_seeds

    env = make_demo_conditioned_env("door", 0, "panda", "sawyer", HEIGHT, WIDTH, 4, episode_length=3)
    try:
        observation, info = env.reset(seed=7, options={"variation": 3})
        assert info["variation"] == 3 and env.unwrapped.task_description == TASK_SPECS["door"].variations[3].description
        demonstration = env.get_wrapper_attr("demonstration")
        assert demonstration.variation == 3, "the demonstration shows the new variation"
        assert observation["demo"].shape == (4, HEIGHT, WIDTH, 3)
        seeds = episode_seeds(7, 3)
        assert info["seed"] == seeds.agent and info["episode_seed"] == 7, "seeded as variation 3, by the seed rule"
        assert info["demo_seed"] == demonstration.seed == seeds.demo

        _, info = env.reset()  # no seed: one is drawn, and the rule still ties the instances to it
        seeds = episode_seeds(info["episode_seed"], 3)
        assert info["seed"] == seeds.agent
        assert info["demo_seed"] in [seeds.demo + DEMO_RETRY_STRIDE * retry for retry in range(DEMO_ATTEMPTS)]
    finally:
        env.close()


# ---------------------------------------------------------------------------------------------- gymnasium's checker
ACTION_RANGE_ADVICE = "we recommend using a symmetric and normalized space"
"""check_env's advice for RL agents; the action is an absolute pose target in metres and radians (README), the
suite's convention shared by the experts, the datasets and the policy, so it stays."""


def test_gymnasium_env_checker_reports_nothing_else():
    from gymnasium.utils.env_checker import check_env

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env = gymnasium.make("mosaic/Door-v0", robot="panda", image_height=HEIGHT, image_width=WIDTH)
        try:
            check_env(env.unwrapped)
            obs, _ = env.reset(seed=2)  # gymnasium.make's passive checker on a reset and a step
            env.step(_hold_still(obs["agent_pos"]))
        finally:
            env.close()
    messages = [str(w.message) for w in caught if ACTION_RANGE_ADVICE not in str(w.message)]
    assert not messages, messages
