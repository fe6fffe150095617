"""Every row of the paper's Table I through the same commands and the same checks: `lerobot-train
--policy.type=X` on tiny real datasets writes a checkpoint that loads with `from_pretrained`, acts in
`mosaic-eval` (rows side by side, with the confusion matrix) and in `lerobot-eval --env.type=mosaic`, and
`--help` shows the type's options; on tensors, every type has the same shapes in and out, follows its
demonstration, refuses a demonstration set for other environments, and acts frame by frame as training computes.
A type's own parts are tested in its own file."""

import json
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
import torch
from pipelines.experiments.presets import CPU_MOSAIC_OPTIONS
from tests.helpers.policy import (
    HEIGHT,
    IMAGE_KEY,
    POLICY_TYPES,
    WIDTH,
    lerobot_train_help,
    random_batch,
    small_config,
    small_flags,
)

BIN = Path(sys.executable).parent
BASELINES = [t for t in POLICY_TYPES if t != "mosaic"]
OWN_OPTION = {  # an option of each type's own, with its help text
    "tosil": ("--policy.point_loss_weight", "point-prediction"),
    "lstm_osil": ("--policy.n_lstm_layers", "Stacked LSTM layers"),
    "mlp_osil": ("--policy.n_context_layers", "Hidden layers of the context MLP"),
    "daml": ("--policy.inner_lr", "Initial inner learning rate"),
}


def _run(command: str, args: list[str], cwd: Path, timeout: int = 600) -> subprocess.CompletedProcess:
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled", "OMP_NUM_THREADS": "1"}
    return subprocess.run([str(BIN / command), *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)


@pytest.mark.parametrize("policy_type", BASELINES)
def test_lerobot_train_help_shows_each_baselines_options(policy_type):
    option, text = OWN_OPTION[policy_type]
    help_text = lerobot_train_help(policy_type)
    assert option in help_text and text in help_text
    assert "--policy.demo_repo_id" in help_text  # the shared demo-conditioning options
    assert "--policy.vision_backbone" in help_text and "4 strided convs" in help_text


@pytest.mark.parametrize("policy_type", POLICY_TYPES)
def test_every_policy_learns_a_fixed_batch_and_round_trips_through_from_pretrained(policy_type, tmp_path):
    """The same shapes in and out for every type; 40 Adam steps lower its loss on one batch; a saved policy acts
    exactly as the one that was saved."""
    from mosaic_policy import policy_class

    torch.manual_seed(0)
    config = small_config(policy_type=policy_type, augment=False)
    policy = policy_class(policy_type)(config).train()
    batch = random_batch(config)
    optimizer = torch.optim.Adam(policy.get_optim_params(), lr=2e-3)
    losses = []
    for _ in range(40):
        loss, _ = policy.forward(batch)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        policy.update() if hasattr(policy, "update") else None
        losses.append(loss.item())
    assert losses[-1] < losses[0] * 0.9, losses

    policy.eval().save_pretrained(tmp_path / "ckpt")
    loaded = policy_class(policy_type).from_pretrained(tmp_path / "ckpt").eval()
    original, reloaded = policy.state_dict(), loaded.state_dict()
    assert original.keys() == reloaded.keys() and all(torch.equal(original[k], reloaded[k]) for k in original)
    chunks, frame = _chunks_after_one_demo(policy, loaded)
    for model in (policy, loaded):
        assert model.select_action(frame).shape == (2, 7)
    assert chunks[0].shape == (2, config.action_chunk, 7)
    torch.testing.assert_close(chunks[0], chunks[1])


@pytest.fixture(scope="module")
def trained_checkpoints(door_datasets, tmp_path_factory):
    """One `lerobot-train` run of 2 steps per policy type on the tiny door datasets: type -> pretrained_model. The
    runs are independent single-threaded processes, so they run side by side, one per core."""
    agent_root, demo_root = door_datasets
    base = tmp_path_factory.mktemp("runs")

    def train(policy_type: str) -> subprocess.CompletedProcess:
        return _run(
            "lerobot-train",
            [
                f"--policy.type={policy_type}",
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
                f"--output_dir={base / policy_type}",
                "--policy.train_obs_frames=3",
                "--policy.embed_dim=32",
                "--policy.head_hidden_dim=32",
                "--policy.demo_loader_threads=1",
                "--policy.weight_average_decay=0.9",  # every type acts below with its averaged weights (MOSAIC: the preset's)
                *small_flags(policy_type),
                *(CPU_MOSAIC_OPTIONS if policy_type == "mosaic" else ()),  # MOSAIC as the cpu preset trains it
            ],
            base,
        )

    with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        results = dict(zip(POLICY_TYPES, pool.map(train, POLICY_TYPES), strict=True))
    for policy_type, result in results.items():
        assert result.returncode == 0, f"{policy_type}:\n" + result.stdout[-3000:] + result.stderr[-3000:]
        assert "[robosuite" not in result.stdout + result.stderr  # training does not load the simulator
    return {policy_type: base / policy_type / "checkpoints" / "last" / "pretrained_model" for policy_type in POLICY_TYPES}


def test_every_trained_checkpoint_loads_through_lerobots_factory_and_acts(trained_checkpoints):
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    import mosaic_policy  # noqa: F401  (what the plugin import does inside lerobot-train and lerobot-eval)

    for policy_type, checkpoint in trained_checkpoints.items():
        config = PreTrainedConfig.from_pretrained(checkpoint)
        assert config.type == policy_type and config.demo_root is None
        if policy_type == "mosaic":  # the cpu preset's checkpoints act with ensembling and averaged weights by default
            assert config.temporal_ensemble_coeff == 0.01 and config.weight_average_decay == 0.998
        policy = get_policy_class(policy_type).from_pretrained(checkpoint, config=config).eval()
        assert policy.acting_model is policy.averaged_model and int(policy.weight_average_updates) == 2, policy_type
        preprocessor, postprocessor = make_pre_post_processors(config, pretrained_path=str(checkpoint))
        policy.reset()
        policy.set_demo(torch.randint(0, 255, (20, HEIGHT, 56, 3), dtype=torch.uint8))
        batch = preprocessor({IMAGE_KEY: torch.rand(3, HEIGHT, 56), "observation.state": torch.randn(10), "task": "x"})
        action = postprocessor(policy.select_action(batch))
        assert action.shape == (1, 7) and torch.isfinite(action).all(), policy_type


def test_the_demo_dependence_bench_compares_the_right_and_a_wrong_demonstration(trained_checkpoints, door_datasets, tmp_path, capsys):
    """`python -m pipelines.bench.demo_dependence` on a lerobot-train checkpoint and LeRobot datasets: a table per
    variation of the pair, every tenth of the episode, distances in cm; the policy's targets move with the
    demonstration; a folder without the datasets is one line naming the command that makes them."""
    from pipelines.bench import demo_dependence

    agent_root, demo_root = door_datasets
    (tmp_path / "mosaic").mkdir()
    (tmp_path / "mosaic" / "door_panda").symlink_to(agent_root)
    (tmp_path / "mosaic" / "door_sawyer").symlink_to(demo_root)
    checkpoint = str(trained_checkpoints["mosaic"])
    demo_dependence.main(["--policy.path", checkpoint, "--data-dir", str(tmp_path), "--variations", "0,1",
                          "--episodes", "1", "--demos", "1", "--every", "3"])
    rows = [line.strip("|").split("|") for line in capsys.readouterr().out.splitlines() if line.startswith("| ") and "%" in line]
    assert len(rows) == 2 * demo_dependence.PARTS and all(len(row) == 4 for row in rows)
    assert all(float(value) >= 0 for row in rows for value in row[1:])

    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    policy_agent = demo_dependence.load_policy(trained_checkpoints["mosaic"])
    agent_data, demo_data = (LeRobotDataset(f"mosaic/door_{robot}", root=tmp_path / "mosaic" / f"door_{robot}")
                             for robot in ("panda", "sawyer"))
    table = demo_dependence.dependence_table(
        policy_agent, demo_dependence.episodes_of(agent_data, 0, 1),
        [demo_dependence.episodes_of(demo_data, 0, 1)[0][0]], [demo_dependence.episodes_of(demo_data, 1, 1)[0][0]], 3,
    )
    # Two training steps leave the targets' bins nearly blind to the demonstration: right - wrong may read 0.
    assert table.shape == (demo_dependence.PARTS, 3) and np.isfinite(table).all() and (table[:, :2] > 0).any()

    with pytest.raises(SystemExit, match="no dataset at .*mosaic-data collect --task door"):
        demo_dependence.main(["--policy.path", checkpoint, "--data-dir", str(tmp_path / "none")])


def test_the_demo_separation_bench_places_fresh_demonstrations_by_the_training_ones(trained_checkpoints, door_datasets, tmp_path, capsys):
    """`python -m pipelines.bench.demo_separation` on a lerobot-train MOSAIC checkpoint, its Sawyer dataset and new
    expert demonstrations: a row per vector MOSAIC's heads read, counts out of the demonstrations used; a baseline's
    checkpoint or a folder without the dataset is one line naming the fix."""
    from pipelines.bench import demo_separation

    _, demo_root = door_datasets
    (tmp_path / "mosaic").mkdir()
    (tmp_path / "mosaic" / "door_sawyer").symlink_to(demo_root)
    checkpoint = str(trained_checkpoints["mosaic"])
    demo_separation.main(["--policy.path", checkpoint, "--data-dir", str(tmp_path), "--variations", "0,1", "--demos", "1",
                          "--fresh", "1"])
    rows = [line.strip("|").split("|") for line in capsys.readouterr().out.splitlines() if line.startswith("| ") and "/" in line]
    assert [row[0].strip() for row in rows][0] == "demonstration embedding"
    for row in rows:
        assert row[1].strip() == "2/2"  # one demonstration per variation is its own centroid
        fresh = int(row[2].strip().split("/")[0])
        assert row[2].strip().endswith("/2") and 0 <= fresh <= 2 and row[3].strip().startswith("0: ")

    with pytest.raises(SystemExit, match="is a mlp_osil policy.*--policy.type=mosaic"):
        demo_separation.main(["--policy.path", str(trained_checkpoints["mlp_osil"]), "--data-dir", str(tmp_path)])
    with pytest.raises(SystemExit, match="no dataset at .*mosaic-data collect --task door"):
        demo_separation.main(["--policy.path", checkpoint, "--data-dir", str(tmp_path / "none")])


def test_the_demo_mixture_bench_measures_how_far_the_demonstration_moves_the_head(trained_checkpoints, door_datasets, tmp_path, capsys):
    """`python -m pipelines.bench.demo_mixture` on lerobot-train checkpoints and LeRobot datasets: a row per tenth of
    the episode with the heaviest component's weight (in (1/M, 1]), the weights' total variation over the
    demonstrations (in [0, 1]) and the last targets' spread in cm; a bad variation is one line."""
    from pipelines.bench import demo_mixture

    agent_root, demo_root = door_datasets
    (tmp_path / "mosaic").mkdir()
    (tmp_path / "mosaic" / "door_panda").symlink_to(agent_root)
    (tmp_path / "mosaic" / "door_sawyer").symlink_to(demo_root)
    for policy_type in ("mosaic", "mlp_osil"):
        demo_mixture.main(["--policy.path", str(trained_checkpoints[policy_type]), "--data-dir", str(tmp_path),
                           "--variations", "0,1", "--episodes", "1", "--every", "3"])
        rows = [line.strip("|").split("|") for line in capsys.readouterr().out.splitlines() if line.startswith("| ") and "%" in line]
        assert len(rows) == demo_mixture.PARTS, policy_type
        values = np.array([[float(value) for value in row[1:]] for row in rows if row[1].strip() != "-"])
        assert len(values) >= 3 and values.shape[1] == 3, policy_type  # a tenth without a sampled frame reads "-"
        n_mixtures = _config_value(trained_checkpoints[policy_type], "n_mixtures")
        assert ((values[:, 0] >= 1 / n_mixtures - 1e-6) & (values[:, 0] <= 1)).all()
        assert ((values[:, 1] >= 0) & (values[:, 1] <= 1)).all() and (values[:, 2] >= 0).all()

    with pytest.raises(SystemExit, match="--shown takes one of door's 4 variations"):
        demo_mixture.main(["--policy.path", str(trained_checkpoints["mosaic"]), "--data-dir", str(tmp_path), "--shown", "7"])


def _config_value(checkpoint, name):
    return json.loads((Path(checkpoint) / "config.json").read_text())[name]


def test_mosaic_eval_puts_every_policy_side_by_side_with_its_confusion_matrix(trained_checkpoints, tmp_path):
    output = tmp_path / "eval" / "results.json"
    paths = [f"--policy.path={checkpoint}" for checkpoint in trained_checkpoints.values()]
    result = _run(
        "mosaic-eval",
        [*paths, "--task", "door", "--variations", "0,1", "--episodes-per-variation", "1", "--max-steps", "5",
         "--workers", "1", "--output", str(output)],
        tmp_path,
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    results = json.loads(output.read_text())
    assert set(results["tables"]) == set(POLICY_TYPES)  # one row per policy type
    table = output.with_suffix(".md").read_text()
    assert all(policy_type in table for policy_type in POLICY_TYPES)
    for policy_type in POLICY_TYPES:
        assert (output.parent / f"confusion_door_{policy_type}.png").stat().st_size > 0


def test_lerobots_evaluation_loop_runs_every_baseline_on_the_mosaic_env(trained_checkpoints):
    """LeRobot's own `eval_policy` (what `lerobot-eval --env.type=mosaic` runs; the command itself runs in
    tests/evaluation/test_same_numbers.py) with every baseline's checkpoint, policy and processors built by LeRobot's
    factories as the command builds them, on one mosaic environment."""
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.envs.factory import make_env, make_env_pre_post_processors
    from lerobot.policies.factory import make_policy, make_pre_post_processors
    from lerobot.scripts.lerobot_eval import eval_policy

    from pipelines.evaluation.agents import register_policy_types
    from pipelines.evaluation.lerobot_env import MosaicEnv

    register_policy_types()
    env_config = MosaicEnv(task="door", variations=[0], observation_height=HEIGHT, observation_width=WIDTH,
                           episode_length=4)
    env = make_env(env_config, n_envs=1)["door"][0]
    try:
        for policy_type in BASELINES:
            checkpoint = trained_checkpoints[policy_type]
            policy_config = PreTrainedConfig.from_pretrained(checkpoint)
            policy_config.pretrained_path = checkpoint
            policy = make_policy(cfg=policy_config, env_cfg=env_config).eval()
            assert policy.name == policy_type
            preprocessor, postprocessor = make_pre_post_processors(
                policy_cfg=policy_config, pretrained_path=str(checkpoint),
                preprocessor_overrides={"device_processor": {"device": "cpu"}},
            )
            env_processors = make_env_pre_post_processors(env_cfg=env_config, policy_cfg=policy_config)
            with torch.no_grad():
                info = eval_policy(env, policy, *env_processors, preprocessor, postprocessor, n_episodes=1)
            assert len(info["per_episode"]) == 1, policy_type
    finally:
        env.close()


def test_importing_the_package_registers_exactly_the_policy_types_with_lerobot():
    """`import mosaic_policy` (what the plugin does) registers every type of POLICY_TYPES and no other; a type
    outside it is refused by name."""
    from lerobot.configs.policies import PreTrainedConfig

    from mosaic_policy import policy_class

    known = PreTrainedConfig.get_known_choices()
    ours = [t for t in known if PreTrainedConfig.get_choice_class(t).__module__.startswith("mosaic_policy.")]
    assert sorted(ours) == sorted(POLICY_TYPES)
    with pytest.raises(ValueError, match="choose from mosaic, tosil"):
        policy_class("act")


def test_policies_are_models_no_simulator_and_no_command_line():
    """Building and running every policy type loads no simulator, and no policy reads the command line (the run's
    length, episodes and loss weights come through LeRobot's own channels and the shared conditioning layer)."""
    code = (
        "import sys; import torch; from tests.helpers.policy import random_batch, small_config; "
        "from mosaic_policy import POLICY_TYPES, policy_class\n"
        "for t in POLICY_TYPES:\n"
        "    config = small_config(policy_type=t)\n"
        "    policy_class(t)(config).forward(random_batch(config))\n"
        "loaded = sorted(m for m in ('robosuite', 'mujoco', 'metaworld', 'mosaic_data.tasks.base') if m in sys.modules)\n"
        "assert not loaded, loaded\n"
    )
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1"}
    result = subprocess.run([sys.executable, "-c", code], cwd=Path(__file__).parents[2], env=env, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr[-2000:]
    package = Path(__file__).parents[2] / "mosaic_policy"
    for source in package.rglob("*.py"):
        text = source.read_text()
        assert "sys.argv" not in text and "parse_arg(" not in text, source


@pytest.mark.parametrize("policy_type", POLICY_TYPES)
def test_gradients_reach_every_trainable_parameter_and_lerobots_factory_finds_the_class(policy_type):
    from lerobot.policies.factory import get_policy_class

    from mosaic_policy import policy_class

    assert get_policy_class(policy_type) is policy_class(policy_type)
    config = small_config(policy_type=policy_type)
    policy = policy_class(policy_type)(config).train()
    loss, _ = policy.forward(random_batch(config, seed=1))
    loss.backward()
    missing = [name for name, p in policy.named_parameters() if p.requires_grad and (p.grad is None or not p.grad.abs().sum() > 0)]
    assert not missing


@pytest.mark.parametrize("policy_type", POLICY_TYPES)
def test_every_policy_trains_acts_and_round_trips_with_the_conv_trunk(policy_type, tmp_path):
    """`vision_backbone="conv"` builds the small trunk in every type, at the width `conv_channels` sets (every
    task context and head follows it) and with `conv_keypoints`: a training step reaches every trainable parameter
    (the keypoints' convolution too), the saved config.json keeps the choice, and the loaded policy acts exactly
    as the saved one (with its BatchNorm-folded inference copy of the trunk)."""
    from lerobot.configs.policies import PreTrainedConfig

    from mosaic_policy import policy_class
    from mosaic_policy.common.conv_trunk import ConvTrunk

    torch.manual_seed(0)
    config = small_config(policy_type=policy_type, vision_backbone="conv", conv_channels=64, conv_keypoints=4)
    policy = policy_class(policy_type)(config).train()
    assert isinstance(policy.model.trunk, ConvTrunk) and policy.model.feature_shape == (64, 2, 4)
    assert policy.model.trunk.n_keypoints == 4
    assert all(isinstance(m, ConvTrunk) for name, m in policy.named_children() if name == "target_trunk")
    optimizer = torch.optim.Adam(policy.get_optim_params(), lr=1e-3)
    loss, _ = policy.forward(random_batch(config, seed=1))
    optimizer.zero_grad()
    loss.backward()
    missing = [name for name, p in policy.named_parameters() if p.requires_grad and (p.grad is None or not p.grad.abs().sum() > 0)]
    assert torch.isfinite(loss) and not missing
    optimizer.step()
    policy.update()

    policy.eval().save_pretrained(tmp_path / "ckpt")
    saved = PreTrainedConfig.from_pretrained(tmp_path / "ckpt")
    assert saved.vision_backbone == "conv" and saved.conv_channels == 64 and saved.conv_keypoints == 4
    loaded = policy_class(policy_type).from_pretrained(tmp_path / "ckpt").eval()
    assert loaded.config.vision_backbone == "conv" and isinstance(loaded.model.trunk, ConvTrunk)
    assert loaded.model.feature_shape == (64, 2, 4)
    original, reloaded = policy.state_dict(), loaded.state_dict()
    assert original.keys() == reloaded.keys() and all(torch.equal(original[k], reloaded[k]) for k in original)
    chunks, _ = _chunks_after_one_demo(policy, loaded)
    for model in (policy, loaded):
        assert isinstance(model.trunk_for_inference(), ConvTrunk) and model.trunk_for_inference() is not model.model.trunk
    torch.testing.assert_close(chunks[0], chunks[1])


def _chunks_after_one_demo(*policies) -> tuple[list[torch.Tensor], dict]:
    """Each policy reset, shown the same random demonstration, then asked for a chunk on the same frame."""
    demo = torch.randint(0, 255, (12, HEIGHT, 56, 3), dtype=torch.uint8)
    frame = {IMAGE_KEY: torch.rand(2, 3, HEIGHT, 56), "observation.state": torch.randn(2, 10)}
    chunks = []
    for model in policies:
        model.reset()
        model.set_demo(demo)
        chunks.append(model.predict_action_chunk(frame))
    return chunks, frame


def test_the_comparison_benchmark_prints_every_policy_as_a_ratio_to_mosaic(tmp_path, capsys):
    from pipelines.bench.policy_compare import main

    output = tmp_path / "compare.json"
    main(["--height", "32", "--width", "56", "--batch-size", "2", "--steps", "1", "--calls", "2", "--output", str(output),
          "--vision-backbone", "conv", "--action-chunk", "10"])
    table = capsys.readouterr().out
    assert "| MOSAIC (`mosaic`) | " in table and "(1.00x)" in table and "conv) | steps per hour |" in table
    recorded = json.loads(output.read_text())
    assert (recorded["settings"]["vision_backbone"], recorded["settings"]["action_chunk"]) == ("conv", 10)
    rows = recorded["rows"]
    assert [row["policy"] for row in rows] == POLICY_TYPES
    assert all(row["parameters"] > 0 and row["train_step_s"] > 0 and row["query_ms"] > 0 for row in rows)


# -- the same behaviour on tensors, every type ------------------------------------------------------------

LOSSES = {
    "mosaic": {"bc_loss", "inverse_loss", "contrastive_loss"},
    "tosil": {"bc_loss", "inverse_loss", "point_loss"},
    "lstm_osil": {"bc_loss", "inverse_loss"},
    "mlp_osil": {"bc_loss", "inverse_loss"},
    "daml": {"bc_loss", "adaptation_loss", "inner_lr"},
}
"""The figures each type's training step logs besides the total."""
EMBEDDING_KINDS = [
    ("mosaic", {}),
    ("mosaic", {"attention_pattern": "full"}),
    ("mosaic", {"demo_summary": True, "summary_hidden_dim": 32, "summary_dim": 16}),
    ("tosil", {}),
    ("lstm_osil", {"lstm_dropout": 0.5}),  # dropout must be off when acting
    ("mlp_osil", {}),
]
"""Types (and MOSAIC's full-attention and demo-summary variants) whose heads read `model.observation_embeddings`;
DAML's come from weights adapted per demonstration (tests/policy/test_daml.py)."""


def _policy(policy_type: str, **overrides):
    from mosaic_policy import policy_class

    torch.manual_seed(0)
    return policy_class(policy_type)(small_config(policy_type=policy_type, **overrides))


def _frames(n_envs: int, n_frames: int, seed: int = 5) -> torch.Tensor:
    return torch.rand(n_envs, n_frames, 3, HEIGHT, WIDTH, generator=torch.Generator().manual_seed(seed))


def _same_distribution(actual, expected, atol: float = 1e-5) -> None:
    for name in ("logit_probs", "means", "log_scales"):
        torch.testing.assert_close(getattr(actual, name), getattr(expected, name), atol=atol, rtol=0)


@pytest.mark.parametrize("policy_type", POLICY_TYPES)
def test_shapes_through_the_model_and_the_policy(policy_type):
    policy = _policy(policy_type)
    config = policy.config
    batch = random_batch(config)
    assert policy.model.feature_shape == (256, 2, 4)
    if policy_type != "daml":
        embeddings = policy.model.observation_embeddings(policy.model.trunk, batch["demo_frames"], batch[IMAGE_KEY])
        assert embeddings.shape == (4, config.train_obs_frames, config.embed_dim)
        distribution = policy.model.action_distribution(embeddings, None)
        assert distribution.means.shape == (4, config.train_obs_frames, 7 * config.action_chunk, config.n_mixtures)
    policy.train()
    loss, info = policy.forward(batch)
    assert loss.dim() == 0 and loss.dtype == torch.float32 and torch.isfinite(loss)
    assert set(info) - {"loss", "demo_wait_s"} == LOSSES[policy_type]
    per_sample, _ = policy.forward(batch, reduction="none")
    assert per_sample.shape == (4,)

    policy.eval()
    policy.reset()
    policy.set_demo(torch.rand(config.n_demo_frames, 3, HEIGHT, WIDTH))  # one demo shared by 2 environments
    observation = {IMAGE_KEY: torch.rand(2, 3, HEIGHT, WIDTH), "observation.state": torch.randn(2, 10)}
    action = policy.select_action(observation)
    assert action.shape == (2, 7) and action.dtype == torch.float32
    assert policy.predict_action_chunk(observation).shape == (2, config.action_chunk, 7)
    policy.reset()
    assert not policy.has_demo
    policy.set_demo(batch["demo_frames"][:2])  # one demo per environment
    assert policy.predict_action_chunk(observation).shape == (2, config.action_chunk, 7)


@pytest.mark.parametrize("policy_type", POLICY_TYPES)
def test_a_demo_for_other_environments_is_a_clear_error(policy_type):
    policy = _policy(policy_type).eval()
    policy.set_demo(_frames(3, policy.config.n_demo_frames))
    with pytest.raises(ValueError, match="one demonstration per environment"):
        policy.predict_action_chunk({IMAGE_KEY: torch.rand(2, 3, HEIGHT, WIDTH)})
    policy.reset()
    policy.set_demo(_frames(1, policy.config.n_demo_frames))  # one for all: any number of environments
    assert policy.predict_action_chunk({IMAGE_KEY: torch.rand(2, 3, HEIGHT, WIDTH)}).shape == (2, 2, 7)


@pytest.mark.parametrize("policy_type", POLICY_TYPES)
def test_use_state_feeds_the_robot_state_to_the_action_head(policy_type):
    policy = _policy(policy_type, use_state=True)
    loss, _ = policy.train().forward(random_batch(policy.config, batch_size=2))
    assert torch.isfinite(loss)
    policy.eval().set_demo(torch.rand(policy.config.n_demo_frames, 3, HEIGHT, WIDTH))
    image = torch.rand(2, 3, HEIGHT, WIDTH)
    with pytest.raises(ValueError, match="observation.state"):
        policy.predict_action_chunk({IMAGE_KEY: image})
    assert policy.predict_action_chunk({IMAGE_KEY: image, "observation.state": torch.randn(2, 10)}).shape == (2, 2, 7)
    with torch.no_grad():
        means = [policy.chunk_distribution(image, state, policy._context).means for state in torch.randn(2, 2, 10)]
    assert not torch.equal(means[0], means[1])


@pytest.mark.parametrize("policy_type", POLICY_TYPES)
def test_actions_depend_on_the_demonstration(policy_type):
    policy = _policy(policy_type, inner_lr=1.0) if policy_type == "daml" else _policy(policy_type)
    policy.eval()  # DAML's large inner step: its demos' effect shows at initialisation
    image = torch.rand(2, 3, HEIGHT, WIDTH)
    shape = (1, policy.config.n_demo_frames, 3, HEIGHT, WIDTH)
    means = []
    for demo in (torch.zeros(shape), torch.zeros(shape), torch.ones(shape)):  # a dark demo twice, then a bright one
        policy.reset()
        policy.set_demo(demo)
        with torch.no_grad():
            means.append(policy.chunk_distribution(image, None, policy._context).means)
    assert torch.equal(means[0], means[1])
    # at initialisation the demo's effect is small but far above float rounding (about 1e-7)
    assert (means[0] - means[2]).abs().max() > 1e-4


@pytest.mark.parametrize("policy_type, options", EMBEDDING_KINDS)
def test_acting_frame_by_frame_computes_what_training_computes(policy_type, options):
    """Frame k acted on after frames 0..k-1 gets the distribution training gives the last frame of a sample of
    the last train_obs_frames frames (policies with a memory of past frames remember that many query frames; the
    others read the current frame alone, which training computes the same way). One demo for 2 environments;
    a new episode forgets the frames; `select_action` queries once per chunk and hands out its targets in order."""
    policy = _policy(policy_type, **options).eval()
    t, chunk = policy.config.train_obs_frames, policy.config.action_chunk
    demo = _frames(1, policy.config.n_demo_frames, seed=4)
    frames = _frames(2, t + 2)  # more frames than a sample holds
    policy.reset()
    policy.set_demo(demo)
    trunk = policy.trunk_for_inference()  # the BatchNorm-folded copy acting uses; the same on both sides here
    with torch.no_grad():
        expected = []
        for k in range(t + 2):
            window = frames[:, max(0, k - t + 1) : k + 1]
            embeddings = policy.model.observation_embeddings(trunk, demo.expand(2, -1, -1, -1, -1), window)
            expected.append(policy.model.action_distribution(embeddings[:, -1], None))
        for k in range(t + 2):
            _same_distribution(policy.chunk_distribution(frames[:, k], None, policy._context), expected[k])

    policy.set_demo(demo)
    for k in range(t + 2):
        mode = expected[k].mode().reshape(2, chunk, 7)
        for j in range(chunk):
            torch.testing.assert_close(policy.select_action({IMAGE_KEY: frames[:, k]}), mode[:, j], atol=2 / 255, rtol=0)


@pytest.mark.parametrize("policy_type, options", EMBEDDING_KINDS)
def test_a_frame_never_sees_later_observation_frames(policy_type, options):
    policy = _policy(policy_type, **options).eval()
    batch = random_batch(policy.config, batch_size=2, seed=4)
    obs = batch[IMAGE_KEY]
    for t in range(obs.shape[1] - 1):
        perturbed = obs.clone()
        perturbed[:, t + 1] = torch.rand_like(perturbed[:, t + 1])
        with torch.no_grad():
            before, after = (
                policy.model.observation_embeddings(policy.model.trunk, batch["demo_frames"], frames)
                for frames in (obs, perturbed)
            )
        torch.testing.assert_close(after[:, : t + 1], before[:, : t + 1], atol=1e-6, rtol=0)
        assert not torch.allclose(after[:, t + 1], before[:, t + 1], atol=1e-4)
