"""Quiet, light start-up: robosuite's harmless import warnings are gone (real ones stay), commands that need no
simulator do not import robosuite (nor torch for the help texts), LeRobot's merge bars stay off our terminal,
and a stopped collection worker leaks no semaphore.

Each check runs in a fresh interpreter (what a user's command is), so modules this test process already
imported do not hide an import.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "MUJOCO_GL": "egl", "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled", "OMP_NUM_THREADS": "1"}
HARMLESS = ("No private macro file", "private macro file", "setup_macros.py", "robosuite_models", "mink-based")


def run_python(code: str, timeout: int = 300) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)], cwd=REPO, env=ENV, capture_output=True, text=True, timeout=timeout
    )


def loaded_after(code: str) -> set[str]:
    """Which of robosuite, torch, lerobot, cv2 and mujoco a fresh interpreter has imported after running ``code``."""
    result = run_python(
        textwrap.dedent(code)
        + "\nimport sys\nprint('LOADED:' + ','.join(m for m in ('robosuite', 'torch', 'lerobot', 'cv2', 'mujoco') if m in sys.modules))\n"
    )
    assert result.returncode == 0, result.stderr[-3000:]
    line = next(line for line in result.stdout.splitlines() if line.startswith("LOADED:"))
    return {name for name in line[len("LOADED:"):].split(",") if name}


# -- robosuite's warnings --------------------------------------------------------------------------------


def test_harmless_robosuite_import_warnings_are_gone_and_real_ones_print_once():
    """Under a root handler (as LeRobot and our workers set up) robosuite's real warnings print once, and its
    harmless import-time notices not at all."""
    result = run_python(
        """
        import logging
        logging.basicConfig(level=logging.INFO)  # a root handler, like lerobot-train's
        import mosaic_data.tasks.base  # imports robosuite
        from robosuite.utils.log_utils import ROBOSUITE_DEFAULT_LOGGER
        ROBOSUITE_DEFAULT_LOGGER.warning("a real robosuite warning 1234")
        ROBOSUITE_DEFAULT_LOGGER.error("a real robosuite error 5678")
        """
    )
    assert result.returncode == 0, result.stderr[-3000:]
    for text in HARMLESS:
        assert text not in result.stderr, result.stderr
    assert result.stderr.count("a real robosuite warning 1234") == 1, result.stderr
    assert result.stderr.count("a real robosuite error 5678") == 1, result.stderr


def test_making_an_environment_prints_nothing_from_robosuite():
    result = run_python(
        """
        import gymnasium, mosaic_data
        env = gymnasium.make("mosaic/Door-v0", variation=1, robot="panda", render_mode=None)
        env.close()
        """
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert "[robosuite" not in result.stderr, result.stderr


# -- what loads robosuite --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "code",
    [
        "from mosaic_data.cli import build_parser; build_parser()",
        "import mosaic_data.collection.validate, mosaic_data.collection.merge, mosaic_data.collection.hub",
        "import mosaic_data.collection.collect",
        "from mosaic_data.tasks import select_variations, VARIATIONS; select_variations('all', None)",
        "from pipelines.evaluation.cli import build_parser; build_parser()",
    ],
)
def test_command_lines_and_tables_load_no_simulator(code):
    assert loaded_after(code) == set()


def test_help_texts_load_no_heavy_module():
    for code in (
        "from mosaic_data.cli import main\ntry:\n    main(['--help'])\nexcept SystemExit:\n    pass",
        "from pipelines.evaluation.cli import main\ntry:\n    main(['--help'])\nexcept SystemExit:\n    pass",
        # it lists the policy types (mosaic_data.constants.POLICY_TYPES) without importing mosaic_policy
        "from pipelines.experiments.cli import main\ntry:\n    main(['--help'])\nexcept SystemExit:\n    pass",
        "from pipelines.experiments.cli import main\nmain(['run', 'learning', '--preset', 'quick', '--dry-run'])",
        "from mosaic_data.cli import main\nmain(['tasks'])",
    ):
        assert loaded_after(code) == set(), code


def test_bad_arguments_are_refused_before_the_heavy_imports(tmp_path):
    """Task names, variations, the output folder and the Ray address are plain data, checked before LeRobot's
    writer, torch or the simulator is imported: ``collect --task doorr`` and ``mosaic-eval`` with a bad task answer
    at once. One fresh interpreter runs every case."""
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    cases = [
        ("mosaic_data.cli", ["collect", "--task", "doorr"], "did you mean 'door'?"),
        ("mosaic_data.cli", ["collect", "--task", "door", "--variations", "0,9"], "variation 9"),
        ("mosaic_data.cli", ["collect", "--task", "door", "--output-dir", str(blocker / "out")], "not a writable folder"),
        ("mosaic_data.cli", ["collect", "--task", "door", "--ray-address", "auto"], "--ray-address needs --executor ray"),
        ("mosaic_data.cli", ["merge", "a", "b", "--repo-id", "mosaic/ab_panda", "--output-dir", str(blocker)], "a file"),
        ("pipelines.evaluation.cli", ["--baseline", "expert", "--task", "doorr"], "did you mean 'door'?"),
        ("pipelines.evaluation.cli", ["--baseline", "expert", "--task", "door", "--variations", "9"], "0..3"),
        ("pipelines.evaluation.cli", ["--baseline", "expert", "--task", "door", "--ray-address", "auto"], "--executor ray"),
    ]
    result = run_python(
        f"""
        import importlib, sys
        for module, argv, _ in {cases!r}:
            print("STATUS:", importlib.import_module(module).main(argv))
        print("LOADED:" + ",".join(m for m in ("robosuite", "mujoco", "torch", "lerobot", "datasets", "ray") if m in sys.modules))
        """
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert result.stdout.count("STATUS: 2") == len(cases), result.stdout + result.stderr
    errors = result.stderr.strip().splitlines()
    assert len(errors) == len(cases), result.stderr
    for line, (module, _, words) in zip(errors, cases):
        assert line.startswith("mosaic-data: error:" if module == "mosaic_data.cli" else "mosaic-eval: error:"), line
        assert words in line, line
    loaded = next(line for line in result.stdout.splitlines() if line.startswith("LOADED:"))
    assert loaded == "LOADED:", loaded  # none of the heavy modules
    assert not blocker.with_name("out").exists() and sorted(tmp_path.iterdir()) == [blocker]


def test_the_policy_trains_without_the_simulator():
    """The plugin, the policy and a training step with per-task loss weights (suite task strings)."""
    loaded = loaded_after(
        """
        import importlib, torch
        importlib.import_module("lerobot_policy_mosaic")
        from lerobot.configs import FeatureType, PolicyFeature
        from mosaic_data.tasks.spec import VARIATIONS
        from mosaic_policy import MosaicConfig, MosaicPolicy

        config = MosaicConfig(
            device="cpu", push_to_hub=False, train_obs_frames=2, frame_stride=1, action_chunk=1, embed_dim=16,
            head_hidden_dim=16, contrastive="off", n_attention_heads=1, n_attention_layers=1,
            input_features={"observation.images.agentview": PolicyFeature(FeatureType.VISUAL, (3, 32, 56))},
            output_features={"action": PolicyFeature(FeatureType.ACTION, (7,))},
        )
        policy = MosaicPolicy(config)
        door, drawer = VARIATIONS["door"], VARIATIONS["drawer"]
        tasks = [door[0].description, door[1].description, drawer[0].description]
        weights = policy.conditioning.sample_weights({"task": tasks}, 3, "cpu")
        assert torch.allclose(weights, torch.tensor([0.25, 0.25, 0.5])), weights
        batch = {
            "observation.images.agentview": torch.rand(3, 2, 3, 32, 56),
            "action": torch.rand(3, 2, 7) * 2 - 1,
            "demo_frames": torch.rand(3, 4, 3, 32, 56),
            "task": tasks,
        }
        loss, _ = policy.forward(batch)
        loss.backward()
        """
    )
    assert "robosuite" not in loaded and "mujoco" not in loaded


def test_task_classes_take_the_table_of_the_spec_module():
    from mosaic_data.tasks import TASKS
    from mosaic_data.tasks.spec import TASK_SPECS, task_of_variation

    assert list(TASKS) == list(TASK_SPECS)
    for name, task_class in TASKS.items():
        assert task_class.variations is TASK_SPECS[name].variations
        assert task_class.horizon_steps == TASK_SPECS[name].horizon_steps
        assert task_class.task_name == name
    assert task_of_variation()[TASKS["pick_place"].variations[5].description] == "pick_place"
    assert len(task_of_variation()) == sum(len(t.variations) for t in TASKS.values()) == 61


# -- a real collection: validate and merge without the simulator, no LeRobot bars ------------------------


def _collect(output: Path, variation: int) -> None:
    result = subprocess.run(
        [
            sys.executable, "-m", "mosaic_data.cli", "collect", "--task", "press_button", "--robot", "panda",
            "--variations", str(variation), "--episodes", "1", "--workers", "1", "--image-size", "48x88",
            "--output-dir", str(output), "--quiet",
        ],
        cwd=REPO, env=ENV, capture_output=True, text=True, timeout=600,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert "[robosuite" not in result.stderr, result.stderr  # the workers' imports too
    assert "leaked semaphore" not in result.stderr, result.stderr
    # the shards are merged with LeRobot's aggregation in this process: its bars must not break through ours
    assert "Validate all meta data" not in result.stderr and "Copy data and videos" not in result.stderr, result.stderr


@pytest.fixture(scope="module")
def collected(tmp_path_factory) -> Path:
    """Real one-episode datasets (small camera): mosaic/press_button_panda (variation 0) and, beside it,
    mosaic/press_button_b_panda (variation 1)."""
    output, other = tmp_path_factory.mktemp("quiet_datasets"), tmp_path_factory.mktemp("quiet_other")
    _collect(output, 0)
    _collect(other, 1)
    shutil.move(other / "mosaic" / "press_button_panda", output / "mosaic" / "press_button_b_panda")
    return output


def test_validate_runs_without_the_simulator(collected):
    code = f"""
    from mosaic_data.cli import main
    assert main(["validate", "mosaic/press_button_panda", "--output-dir", {str(collected)!r}]) == 0
    """
    assert loaded_after(code) & {"robosuite", "mujoco", "torch"} == set()


def test_merge_runs_without_the_simulator_and_without_lerobots_progress_bars(collected):
    result = run_python(
        f"""
        import sys
        from mosaic_data.cli import main
        status = main([
            "merge", "mosaic/press_button_panda", "mosaic/press_button_b_panda",
            "--repo-id", "mosaic/press_button_twice_panda", "--output-dir", {str(collected)!r},
        ])
        assert status == 0, status
        print("ROBOSUITE:", "robosuite" in sys.modules)
        """
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert "ROBOSUITE: False" in result.stdout
    assert "Validate all meta data" not in result.stderr and "Copy data and videos" not in result.stderr, result.stderr
    assert (collected / "mosaic" / "press_button_twice_panda" / "meta" / "info.json").exists()


# -- Ctrl-C of a multi-worker collection -----------------------------------------------------------------

_STOPPED_WORKER = """
import multiprocessing, time


def worker(ready):
    from mosaic_data.collection.quiet import quiet_dataset_writing

    quiet_dataset_writing()  # what every collection worker does first
    import datasets

    # LeRobot's writer maps every saved episode with datasets.map, whose (disabled) bar made tqdm's first lock
    datasets.Dataset.from_dict({"x": [1, 2]}).map(lambda row: row)
    ready.set()
    time.sleep(120)


if __name__ == "__main__":
    context = multiprocessing.get_context("spawn")
    ready = context.Event()
    process = context.Process(target=worker, args=(ready,))
    process.start()
    assert ready.wait(120)
    process.terminate()  # what the collection does to its workers on Ctrl-C
    process.join()
"""


def test_a_stopped_collection_worker_leaks_no_semaphore(tmp_path):
    script = tmp_path / "stopped_worker.py"
    script.write_text(_STOPPED_WORKER)
    result = subprocess.run([sys.executable, str(script)], cwd=REPO, env=ENV, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "leaked semaphore" not in result.stderr, result.stderr
