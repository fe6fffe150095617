"""The task suite on the real simulator, headless: scenes, images, success tests, determinism, bad input."""

from __future__ import annotations

import random

import gymnasium
import numpy as np
import pytest

import mosaic_data  # noqa: F401  (registers the gymnasium environments)
from mosaic_data.collection.validate import action_jumps, longest_hold
from mosaic_data.envs import gym_id
from mosaic_data.experts import EXPERTS, make_expert
from mosaic_data.experts.base import GraspingExpert
from mosaic_data.rollout import run_expert_episode
from mosaic_data.tasks import TASKS, get_task_class, make_task_env
from mosaic_data.tasks.base import IMAGE_HEIGHT, IMAGE_WIDTH, STATE_DIM

ROBOTS = ("panda", "sawyer")
NON_GRASPING_MAX_HOLD = 2
"""Where the fingers only push (door, drawer, buttons), the experts never hold still longer than this."""
TASK_ROBOT = [(task, robot) for task in TASKS for robot in ROBOTS]


VARIATIONS_PER_RUN = 2
"""Variations per task and robot that the default run rolls out; `-m slow` runs every one of them."""


def all_variations(task: str) -> list[int]:
    return [variation.index for variation in get_task_class(task).variations]


def sampled_variations(task: str, robot: str) -> list[int]:
    """A sample of the task's variations, the same in every run (seeded by task and robot)."""
    variations = all_variations(task)
    return sorted(random.Random(f"{task}/{robot}").sample(variations, min(VARIATIONS_PER_RUN, len(variations))))


def robot_and_table_rows(env) -> tuple[float, float]:
    """Mean image row of the robot's pixels and of the table's, in the orientation render_agentview uses."""
    raw = env.sim.render(camera_name="agentview", height=IMAGE_HEIGHT, width=IMAGE_WIDTH, segmentation=True)
    image = env.render_agentview()
    rgb = env.sim.render(camera_name="agentview", height=IMAGE_HEIGHT, width=IMAGE_WIDTH)
    assert np.array_equal(image, rgb[::-1]) or np.array_equal(image, rgb), "render_agentview is not the camera image"
    segmentation = raw[::-1] if np.array_equal(image, rgb[::-1]) else raw
    geom_ids = segmentation[..., 1]
    model = env.sim.model
    robot_geoms = [i for i in range(model.ngeom) if model.body(model.geom_bodyid[i]).name.startswith("robot0")]
    table_geoms = [i for i in range(model.ngeom) if model.body(model.geom_bodyid[i]).name == "table"]
    rows = np.arange(IMAGE_HEIGHT)[:, None].repeat(IMAGE_WIDTH, 1)
    robot_mask = np.isin(geom_ids, robot_geoms) & (segmentation[..., 0] == 5)  # mjOBJ_GEOM
    table_mask = np.isin(geom_ids, table_geoms) & (segmentation[..., 0] == 5)
    assert robot_mask.any() and table_mask.any(), "the robot and the table should both be in view"
    return float(rows[robot_mask].mean()), float(rows[table_mask].mean())


def check_resets_and_renders_right_side_up(task_env_cache, task: str, robot: str, variations: list[int]) -> None:
    for variation in variations:
        env = task_env_cache(task, robot, variation)
        env.reset_to_seed(variation)
        image = env.render_agentview()
        assert image.shape == (IMAGE_HEIGHT, IMAGE_WIDTH, 3) and image.dtype == np.uint8
        assert image.std() > 20, "the image is (nearly) blank"
        rows_robot, rows_table = robot_and_table_rows(env)
        # The camera looks over the table towards the robot: the robot stands beyond the table, so it must be
        # drawn above the table. An upside-down image has it the other way round.
        assert rows_robot < rows_table, f"variation {variation}: image looks upside down"
        state = env.robot_state()
        assert state.shape == (STATE_DIM,) and np.all(np.isfinite(state))


@pytest.mark.parametrize(("task", "robot"), TASK_ROBOT)
def test_sampled_variations_reset_and_render_right_side_up(task_env_cache, task, robot):
    check_resets_and_renders_right_side_up(task_env_cache, task, robot, sampled_variations(task, robot))


@pytest.mark.slow
@pytest.mark.parametrize(("task", "robot"), TASK_ROBOT)
def test_every_variation_resets_and_renders_right_side_up(task_env_cache, task, robot):
    check_resets_and_renders_right_side_up(task_env_cache, task, robot, all_variations(task))


def check_expert_episodes(task_env_cache, task: str, robot: str, variations: list[int]) -> None:
    """One expert episode per variation: success within the horizon, a continuous rotation chart, no long hold."""
    failures = []
    for variation in variations:
        env = task_env_cache(task, robot, variation)
        episode = run_expert_episode(env, seed=1000 + variation)
        if not episode.success:
            failures.append(variation)
        else:
            assert episode.length < env.horizon
        # The action's rotation chart is continuous over the suite: no axis-angle flip at pi inside an episode.
        rotations = np.asarray(episode.actions)[:, 3:6]
        assert np.linalg.norm(rotations, axis=1).max() < 2.5, f"{task}/{robot}/{variation}: rotation near the chart's edge"
        jumps = action_jumps(episode.actions)
        assert max(jumps["rx"], jumps["ry"], jumps["rz"]) <= 0.1, f"{task}/{robot}/{variation}: rotation jumps {jumps}"
        if not issubclass(EXPERTS[task], GraspingExpert):  # a one-frame policy would stall in a hold
            hold, step = longest_hold(episode.actions)
            assert hold <= NON_GRASPING_MAX_HOLD, f"{task}/{robot}/{variation}: holds still {hold} steps from step {step}"
    assert not failures, f"{task}/{robot}: expert failed on variations {failures}"


@pytest.mark.parametrize(("task", "robot"), TASK_ROBOT)
def test_expert_succeeds_on_sampled_variations(task_env_cache, task, robot):
    check_expert_episodes(task_env_cache, task, robot, sampled_variations(task, robot))


@pytest.mark.slow
@pytest.mark.parametrize(("task", "robot"), TASK_ROBOT)
def test_expert_succeeds_on_every_variation(task_env_cache, task, robot):
    check_expert_episodes(task_env_cache, task, robot, all_variations(task))


@pytest.mark.parametrize("robot", ROBOTS)
def test_action_rotation_is_the_turn_from_gripper_down(task_env_cache, robot):
    """Action (0, 0, yaw) holds the gripper pointing down, turned by yaw about the vertical; zero is gripper-down."""
    from scipy.spatial.transform import Rotation

    from mosaic_data.tasks.base import GRIPPER_DOWN, action_rotation, rotation_from_action

    env = task_env_cache("press_button", robot, 0)
    env.reset_to_seed(3)
    start = env.eef_pos
    for yaw in (0.0, 0.4):
        for _ in range(40):
            env.step(np.concatenate([start, [0.0, 0.0, yaw], [-1.0]]))
        reached = env.eef_rotation
        assert (reached.inv() * Rotation.from_euler("z", yaw) * GRIPPER_DOWN).magnitude() < 0.05
        np.testing.assert_allclose(action_rotation(reached), [0.0, 0.0, yaw], atol=0.05)
    round_trip = rotation_from_action(action_rotation(Rotation.from_rotvec([0.3, -1.0, 2.0])))
    assert (round_trip.inv() * Rotation.from_rotvec([0.3, -1.0, 2.0])).magnitude() < 1e-9


@pytest.mark.parametrize("task", list(TASKS))
def test_another_variations_goal_is_not_success(task_env_cache, task):
    """Pursue variation j's goal in variation i's scene: j's goal is reached, i's success never fires (two pairs
    per task: the first variation with the last one sharing its scene, and the last with the first)."""
    check_other_goals(task_env_cache, task, thorough=False)


@pytest.mark.slow
@pytest.mark.parametrize("task", list(TASKS))
def test_another_variations_goal_is_not_success_in_six_pairs(task_env_cache, task):
    """The same for the first, middle and last variation, each with the first and last sharing its scene."""
    check_other_goals(task_env_cache, task, thorough=True)


def check_other_goals(task_env_cache, task: str, thorough: bool) -> None:
    n = len(get_task_class(task).variations)

    def initial_state(variation: int) -> np.ndarray:
        env = task_env_cache(task, "panda", variation)
        env.reset_to_seed(7)
        return env.sim.data.qpos.copy()

    # Some variations start from another scene state (a drawer to close starts open): pair each variation
    # with others whose scene starts exactly the same, the only setting where "another goal" is meaningful.
    pairs = []
    for own in (0, n - 1, n // 2) if thorough else (0, n - 1):
        own_state = initial_state(own)
        same_scene = [v for v in range(n) if v != own and np.array_equal(initial_state(v), own_state)]
        assert same_scene, f"no other variation of {task} shares variation {own}'s scene"
        pairs += [(own, same_scene[0]), (own, same_scene[-1])] if thorough else [(own, same_scene[-1 if own == 0 else 0])]
    for own, other in dict.fromkeys(pairs):
        env = task_env_cache(task, "panda", own)
        env.reset_to_seed(7)
        expert = make_expert(env, variation=other)
        own_success_seen = False
        for _ in range(env.horizon):
            env.step(expert.act())
            own_success_seen |= env.check_success()
            if env.check_success(variation=other):
                break
        assert env.check_success(variation=other), f"expert of variation {other} did not reach its goal"
        assert not own_success_seen, f"variation {own} counted variation {other}'s goal as its success"


@pytest.mark.parametrize("task", list(TASKS))
def test_same_seed_same_scene_for_both_robots(task_env_cache, task):
    def scene_state(robot: str, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        env = task_env_cache(task, robot, 0)
        env.reset_to_seed(seed)
        robot_qpos_ids = set(env.robot._ref_joint_pos_indexes) | set(env.robot._ref_gripper_joint_pos_indexes["right"])
        scene_qpos = np.array([q for i, q in enumerate(env.sim.data.qpos) if i not in robot_qpos_ids])
        fixture_ids = [i for i in range(env.sim.model.nbody) if not env.sim.model.body(i).name.startswith(("robot", "gripper", "fixed_mount"))]
        return scene_qpos, env.sim.model.body_pos[fixture_ids].copy(), env.sim.data.qpos[env.robot._ref_joint_pos_indexes].copy()

    panda_a, panda_layout_a, panda_joints_a = scene_state("panda", 5)
    panda_b, panda_layout_b, panda_joints_b = scene_state("panda", 5)
    np.testing.assert_array_equal(panda_layout_a, panda_layout_b)
    np.testing.assert_array_equal(panda_a, panda_b)
    np.testing.assert_array_equal(panda_joints_a, panda_joints_b)
    sawyer, sawyer_layout, _ = scene_state("sawyer", 5)
    np.testing.assert_allclose(sawyer_layout[: len(panda_layout_a)], panda_layout_a[: len(sawyer_layout)])
    np.testing.assert_allclose(sawyer, panda_a)
    _, other_layout, other_joints = scene_state("panda", 6)
    assert not np.allclose(other_layout, panda_layout_a) or not np.allclose(other_joints, panda_joints_a)


def test_gymnasium_api_matches_the_issue_example():
    env = gymnasium.make("mosaic/Door-v0", variation=1, robot="panda", render_mode="rgb_array")
    try:
        obs, info = env.reset(seed=3)
        assert obs["pixels"]["agentview"].shape == (IMAGE_HEIGHT, IMAGE_WIDTH, 3)
        assert obs["agent_pos"].shape == (STATE_DIM,) and obs["agent_pos"].dtype == np.float32
        assert info["task"] == get_task_class("door").variations[1].description
        expert = make_expert(env)
        other = make_expert(env, variation=2)
        assert other.variation.index == 2
        for _ in range(env.unwrapped.horizon):
            obs, reward, terminated, truncated, info = env.step(expert.act(obs, env))
            if terminated or truncated:
                break
        assert terminated and info["is_success"] and reward == 1.0
        assert env.render().shape == (IMAGE_HEIGHT, IMAGE_WIDTH, 3)
        again, _ = env.reset(seed=3)
        np.testing.assert_allclose(again["agent_pos"], env.reset(seed=3)[0]["agent_pos"])
    finally:
        env.close()


def test_render_returns_the_observation_frame_without_rendering_again():
    """LeRobot's evaluation calls render() after every step for its videos: that must not cost a second render."""
    env = gymnasium.make("mosaic/Door-v0", image_height=48, image_width=64)
    try:
        obs, _ = env.reset(seed=1)
        renders = []
        task_env = env.unwrapped.task_env
        original = task_env.render_agentview
        task_env.render_agentview = lambda: renders.append(1) or original()
        obs, *_ = env.step(make_expert(env).act(obs, env))
        assert len(renders) == 1
        np.testing.assert_array_equal(env.render(), obs["pixels"]["agentview"])
        assert len(renders) == 1
    finally:
        env.close()
    blind = gymnasium.make("mosaic/Door-v0", image_height=48, image_width=64, observe_image=False)
    try:
        blind.reset(seed=1)
        assert blind.render().shape == (48, 64, 3)  # rendered on request when observations carry no image
    finally:
        blind.close()


def test_a_scene_renders_its_own_frames_while_another_scene_is_alive():
    """An evaluation worker holds the agent's scene and the demonstrator's; robosuite renders in the current GL
    context, the newest scene's, yet each scene's frames come out through its own camera."""
    first = make_task_env("door", 0, "panda", image_height=48, image_width=88)
    first.reset_to_seed(3)
    before = first.render_agentview()
    second = make_task_env("door", 0, "sawyer", image_height=48, image_width=88)
    second.reset_to_seed(3)
    second.render_agentview()
    assert np.array_equal(first.render_agentview(), before), "the first scene's frame changed once a second scene rendered"
    second.close()
    assert np.array_equal(first.render_agentview(), before), "the first scene's frame changed once the second scene closed"
    first.close()


def test_every_task_is_registered_with_gymnasium():
    for task in TASKS:
        assert gym_id(task) in gymnasium.registry


def test_bad_input_gives_clear_errors():
    with pytest.raises(ValueError, match="unknown task 'doors'.*door"):
        make_task_env("doors")
    with pytest.raises(ValueError, match=r"unknown variation 4 for task 'door'.*0\.\.3"):
        make_task_env("door", variation=4)
    with pytest.raises(ValueError, match="unknown variation -1"):
        make_task_env("door", variation=-1)
    with pytest.raises(ValueError, match="unknown robot 'ur5'.*panda, sawyer"):
        make_task_env("door", robot="ur5")
    with pytest.raises(ValueError, match="unknown variation 9"):
        gymnasium.make("mosaic/Door-v0", variation=9)
    env = gymnasium.make("mosaic/Door-v0", observe_image=False)
    try:
        env.reset(seed=0)
        with pytest.raises(ValueError, match="action must have 7 values"):
            env.step(np.zeros(6))
        with pytest.raises(ValueError, match="NaN"):
            env.step(np.full(7, np.nan))
    finally:
        env.close()


@pytest.mark.slow
@pytest.mark.parametrize(("task", "robot"), TASK_ROBOT)
def test_expert_success_table_over_20_seeds(task_env_cache, task, robot):
    for variation in all_variations(task):
        env = task_env_cache(task, robot, variation)
        successes = sum(run_expert_episode(env, seed).success for seed in range(20))
        assert successes >= 19, f"{task}/{robot}/variation {variation}: {successes}/20"


def test_render_buffers_are_frame_sized_and_frames_unchanged(task_env_cache, monkeypatch):
    """The offscreen buffer is the frame's size and there is no shadow map while shadows are off (memory and the
    per-frame clear); a scene built with MuJoCo's default buffers (640x480 and a 4096 shadow map) draws the very
    same pixels, on every task."""
    import mosaic_data.tasks.rendering as task_rendering

    for task in TASKS:
        env = task_env_cache(task, "panda", 0)
        env.reset_to_seed(11)
        context = env.sim._render_context_offscreen.con
        assert (context.offWidth, context.offHeight, context.shadowSize) == (IMAGE_WIDTH, IMAGE_HEIGHT, 0)
        frame = env.render_agentview()
        assert frame.shape == (IMAGE_HEIGHT, IMAGE_WIDTH, 3)
        with monkeypatch.context() as patch:
            patch.setattr(task_rendering, "size_render_buffers", lambda xml, *args, **kwargs: xml)
            reference = make_task_env(task, 0, "panda")
        try:
            reference_context = reference.sim._render_context_offscreen.con
            assert (reference_context.offWidth, reference_context.offHeight) == (640, 480)
            assert reference_context.shadowSize == 4096
            reference.reset_to_seed(11)
            assert np.array_equal(reference.render_agentview(), frame), f"{task}: the frame-sized buffer changed pixels"
        finally:
            reference.close()


def test_shadows_keep_their_shadow_map():
    env = make_task_env("door", 0, "panda", image_height=48, image_width=88, fast_render=False)
    try:
        context = env.sim._render_context_offscreen.con
        assert (context.offWidth, context.offHeight) == (88, 48) and context.shadowSize > 0
        env.reset_to_seed(0)
        assert env.render_agentview().shape == (48, 88, 3)
    finally:
        env.close()


def expert_trace(env, seed: int, steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """States and actions of the expert's first ``steps`` steps from ``seed``, and the frame after them."""
    env.reset_to_seed(seed)
    expert = make_expert(env)
    states, actions = [], []
    for _ in range(steps):
        states.append(env.robot_state())
        actions.append(expert.act())
        env.step(actions[-1])
    return np.array(states), np.array(actions), env.render_agentview()


@pytest.mark.parametrize(("task", "robot"), [(task, "panda") for task in TASKS] + [("door", "sawyer")])
def test_a_scene_switched_to_a_variation_runs_it_as_a_new_scene_would(task_env_cache, task, robot):
    """Collection workers and evaluation keep one scene per task and switch its variation: after another
    variation's episode, a seeded reset must give exactly what a scene built for the variation gives."""
    last = all_variations(task)[-1]
    reused = task_env_cache(task, robot, 0)
    expert_trace(reused, seed=5, steps=25)  # another variation's episode first, left midway
    reused.set_variation(last)
    fresh = make_task_env(task, last, robot)
    try:
        for got, expected in zip(expert_trace(reused, 21, 40), expert_trace(fresh, 21, 40), strict=True):
            assert np.array_equal(got, expected), f"{task}: the switched scene ran variation {last} differently"
    finally:
        fresh.close()
