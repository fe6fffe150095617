"""Recipe plans without running them: deterministic commands, dry runs, presets, clear errors for bad names."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from mosaic_data.tasks.spec import TASK_NAMES, VARIATIONS
from pipelines.experiments import cli
from pipelines.experiments.presets import PRESETS, ExperimentError, resolve_preset
from pipelines.experiments.recipes import RECIPES, build_plan, episodes_fraction

EXPERIMENT = [sys.executable, "-m", "pipelines.experiments.cli"]


@pytest.mark.parametrize("recipe", list(RECIPES))
@pytest.mark.parametrize("preset_name", list(PRESETS))
def test_the_same_arguments_give_the_same_commands(recipe, preset_name, tmp_path):
    preset = resolve_preset(preset_name, [])
    first = build_plan(recipe, preset, tmp_path / "exp")
    second = build_plan(recipe, resolve_preset(preset_name, []), tmp_path / "exp")
    assert [s.command for s in first.stages] == [s.command for s in second.stages]
    assert len({s.key for s in first.stages}) == len(first.stages)
    kinds = [s.kind for s in first.stages]
    assert kinds.count("train") >= 1 and kinds.count("evaluate") >= 1
    # every stage runs only after what it reads has been made: datasets before training, training before evaluation
    made = set()
    for stage in first.stages:
        reads = [Path(a.split("=", 1)[1]) for a in stage.command if a.startswith(("--dataset.root=", "--policy.path="))]
        for path in reads:
            assert made.intersection([path, *path.parents]), f"{stage.key} reads {path} before it is made"
        made.add(stage.output)


def test_paper_preset_is_the_papers_protocol(tmp_path):
    paper = PRESETS["paper"]
    assert (paper.image_size, paper.episodes, paper.batch_size, paper.seeds) == ("100x180", 100, 30, 3)
    assert (paper.eval_checkpoints, paper.eval_episodes) == (3, 10)
    plan = build_plan("single-task", paper, tmp_path)
    trains = [s for s in plan.stages if s.kind == "train"]
    assert len(trains) == len(TASK_NAMES) * 5 * 3  # tasks x methods x seeds
    evaluations = [s for s in plan.stages if s.kind == "evaluate"]
    assert len(evaluations) == len(trains) * 3  # the last three checkpoints of every run
    assert all("--policy.device=cuda" in s.command for s in trains)
    multi = build_plan("multi-task", paper, tmp_path)
    mosaic = next(s for s in multi.stages if s.kind == "train" and "--policy.type=mosaic" in s.command)
    assert "--policy.n_attention_layers=3" in mosaic.command
    assert any(s.kind == "merge" for s in multi.stages)


def test_novel_task_models_never_see_the_held_out_task(tmp_path):
    plan = build_plan("novel-task", PRESETS["paper"], tmp_path, tasks=("door",))
    merges = [s for s in plan.stages if s.kind == "merge"]
    assert merges and all("door_" not in " ".join(s.command[6:]) for s in merges)
    assert {s.command[s.command.index("--task") + 1] for s in plan.stages if s.kind == "evaluate"} == {"door"}


def test_fine_tune_fractions_select_the_first_episodes_of_every_variation(tmp_path):
    assert episodes_fraction("door", 4, 50) == [0, 1, 4, 5, 8, 9, 12, 13]
    assert len(episodes_fraction("pick_place", 100, 25)) == 25 * len(VARIATIONS["pick_place"])
    plan = build_plan("fine-tune", PRESETS["paper"], tmp_path, tasks=("door",))
    trains = [s for s in plan.stages if s.key.startswith("train/fine-tune/")]
    assert len(trains) == 4 * 2 * 3  # fractions x (fine-tune, scratch) x seeds
    fine = next(s for s in trains if "fine-tune-25/seed1" in s.key)
    assert any(a.startswith("--policy.path=") and "novel-task/door/mosaic/seed1" in a for a in fine.command)
    scratch = next(s for s in trains if "scratch-25/seed1" in s.key)
    assert "--policy.type=mosaic" in scratch.command
    selection = next(a for a in fine.command if a.startswith("--dataset.episodes="))
    assert selection == next(a for a in scratch.command if a.startswith("--dataset.episodes="))


@pytest.mark.parametrize("preset_name, backbone", [("paper", "resnet18"), ("cpu", "conv"), ("smoke", "conv")])
def test_every_new_model_gets_the_presets_vision_backbone_and_a_fine_tuned_one_keeps_its_own(preset_name, backbone, tmp_path):
    plan = build_plan("fine-tune", PRESETS[preset_name], tmp_path, tasks=("door",))
    trains = [s for s in plan.stages if s.kind == "train"]
    new = [s for s in trains if any(a.startswith("--policy.type=") for a in s.command)]
    fine = [s for s in trains if any(a.startswith("--policy.path=") for a in s.command)]
    assert new and fine
    assert all(f"--policy.vision_backbone={backbone}" in s.command for s in new)
    assert not any(a.startswith("--policy.vision_backbone=") for s in fine for a in s.command)
    with pytest.raises(ExperimentError, match="vision_backbone='vit': choose resnet18 or conv"):
        resolve_preset(preset_name, ["vision_backbone=vit"])


def test_dry_run_prints_the_commands_and_writes_nothing(tmp_path, capsys):
    output = tmp_path / "exp"
    assert cli.main(["run", "single-task", "--preset", "smoke", "--output", str(output), "--dry-run"]) == 0
    printed = capsys.readouterr().out
    plan = build_plan("single-task", PRESETS["smoke"], output)
    for stage in plan.stages:
        assert stage.shell_line() in printed
    assert not output.exists()


def test_paper_preset_prints_its_gpu_hours(capsys, tmp_path):
    cli.main(["run", "single-task", "--preset", "paper", "--output", str(tmp_path), "--dry-run", "--tasks", "door"])
    assert "GPU-hours" in capsys.readouterr().out


def test_cpu_preset_prints_its_training_hours(capsys, tmp_path):
    # 5 methods x 2250 steps at the 0.7 s per MOSAIC step of the conv trunk at the cpu preset's own sizes, MOSAIC's
    # scaled by 1.09 for the preset's demonstration summary and 1.8 for its wrong-demonstration loss, each
    # baseline's by its measured ratio (0.73 + 0.43 + 0.46 + 0.94): 2250 x 0.7 x (1.962 + 2.56) s = 2.0 hours
    cli.main(["run", "single-task", "--preset", "cpu", "--output", str(tmp_path), "--dry-run", "--tasks", "door"])
    out = capsys.readouterr().out
    assert "training about 2.0 hours on 2 CPU cores (0.7 s per step of the paper's MOSAIC" in out
    assert "; 1.09x with the demonstration summary, 1.8x with the wrong-demonstration loss;" in out
    assert "a baseline's step: tosil 0.73x, lstm_osil 0.43x, mlp_osil 0.46x, daml 0.94x of it)" in out
    # the paper's ResNet-18 trunk at the same sizes: 2.5 s per step, ratios 1.962 + 0.64 + 0.55 + 0.56 + 0.48: 6.5 hours
    cli.main(["run", "single-task", "--preset", "cpu", "--output", str(tmp_path), "--dry-run", "--tasks", "door",
              "--set", "vision_backbone=resnet18"])
    assert "training about 6.5 hours on 2 CPU cores (2.5 s per step of the paper's MOSAIC" in capsys.readouterr().out
    # one baseline alone: LSTM at 0.43x, 2250 x 0.7 x 0.43 s = 11 minutes
    cli.main(["run", "learning", "--preset", "cpu", "--output", str(tmp_path / "lstm"), "--dry-run",
              "--set", "learning_methods=lstm_osil"])
    assert "training about 11 minutes on 2 CPU cores" in capsys.readouterr().out
    # MOSAIC as the preset has it: 2250 x 0.7 x 1.09 x 1.8 s = 52 minutes; the paper's MOSAIC: 26
    cli.main(["run", "learning", "--preset", "cpu", "--output", str(tmp_path / "preset"), "--dry-run"])
    assert "training about 52 minutes on 2 CPU cores" in capsys.readouterr().out
    cli.main(["run", "learning", "--preset", "cpu", "--output", str(tmp_path / "paper_model"), "--dry-run",
              "--set", "mosaic_options="])
    out = capsys.readouterr().out
    assert "training about 26 minutes on 2 CPU cores" in out
    assert "with the demonstration summary" not in out and "with the wrong-demonstration loss" not in out
    # the summary and the wrong demonstration's pass cost only where the last option given turns them on
    for options, minutes in [("--policy.wrong_demo_loss_weight=10", 47),
                             ("--policy.wrong_demo_loss_weight=10 --policy.wrong_demo_loss_weight=0", 26),
                             ("--policy.demo_summary=true", 29),
                             ("--policy.demo_summary=true --policy.demo_summary=false", 26)]:
        cli.main(["run", "learning", "--preset", "cpu", "--output", str(tmp_path / str(minutes)), "--dry-run",
                  "--set", f"mosaic_options={options}"])
        assert f"training about {minutes} minutes on 2 CPU cores" in capsys.readouterr().out


@pytest.mark.parametrize(
    "arguments, message",
    [
        (["run", "single-tsk"], "unknown recipe 'single-tsk': choose one of single-task"),
        (["run", "single-task", "--preset", "huge"], "unknown preset 'huge': choose one of paper"),
        (["run", "single-task", "--tasks", "door,dor"], "unknown task 'dor': choose from door"),
        (["run", "single-task", "--set", "stepz=3"], "bad --set 'stepz=3': use KEY=VALUE"),
        (["run", "single-task", "--set", "steps=many"], "bad --set 'steps=many': steps takes int values"),
        (["run", "single-task", "--set", "methods=mosaic,act"], "preset methods act: choose from mosaic"),
        (["report", "/nonexistent/exp"], "holds no mosaic-experiment run"),
    ],
)
def test_bad_names_give_one_clear_line(arguments, message, tmp_path):
    result = subprocess.run([*EXPERIMENT, *arguments, *(["--dry-run"] if arguments[0] == "run" else [])],
                            capture_output=True, text=True, cwd=tmp_path)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], result.stderr
    assert "Traceback" not in result.stderr


def test_a_folder_keeps_one_preset(tmp_path):
    output = tmp_path / "exp"
    args = cli.parse_args(["run", "single-task", "--preset", "smoke", "--output", str(output)])
    cli._record_settings(output, args, [], None)
    other = cli.parse_args(["run", "fine-tune", "--preset", "cpu", "--output", str(output)])
    with pytest.raises(ExperimentError, match="holds a single-task run with other settings"):
        cli._record_settings(output, other, [], None)
    same = cli.parse_args(["run", "fine-tune", "--preset", "smoke", "--output", str(output)])
    record = cli._record_settings(output, same, [], None)
    assert set(record["recipes"]) == {"single-task", "fine-tune"}
    assert json.loads((output / "experiment.json").read_text()) == record


def test_more_seeds_extend_an_experiment_and_a_dry_run_refuses_what_the_run_would(tmp_path, capsys):
    """A second seed of a finished run goes in the same folder (its first seed's stages are the same); any other
    change is refused by the dry run as by the run (the dry run printed a plan the run then refused)."""
    output = tmp_path / "exp"
    first = ["run", "learning", "--preset", "smoke", "--set", "steps=4", "--output", str(output)]
    cli._record_settings(output, cli.parse_args(first), ["steps=4"], None)
    more = cli.parse_args([*first, "--seeds", "2"])
    record = cli._record_settings(output, more, ["steps=4", "seeds=2"], None)
    assert record["recipes"]["learning"]["overrides"] == ["steps=4", "seeds=2"]
    assert cli.main([*first, "--seeds", "3", "--dry-run"]) == 0
    assert "# train learning/door/mosaic/seed3" in capsys.readouterr().out
    plan = cli.build_plan("learning", cli.resolve_preset("smoke", ["steps=4", "seeds=2"]), output, None)
    seed1 = [stage for stage in plan.stages if "seed1" in stage.title or stage.kind == "collect"]
    for stage in seed1:  # the first seed's stages finished: the estimate counts the second seed's only
        folder = cli.stage_folder(output, stage)
        folder.mkdir(parents=True)
        (folder / "done.json").write_text("{}")
    text = cli.estimate_text(plan, cli.resolve_preset("smoke", ["steps=4", "seeds=2"]), output)
    assert text.startswith(f"{len(plan.stages) - len(seed1)} stages left of {len(plan.stages)} ({len(seed1)} finished before)")
    assert "1 training run (4 steps in all)" in text
    assert cli.main(["run", "learning", "--preset", "smoke", "--set", "steps=6", "--output", str(output), "--dry-run"]) == 2
    assert "holds a learning run with other settings" in capsys.readouterr().err


def test_an_interrupted_stage_resumes_where_it_can(tmp_path):
    from pipelines.experiments.stages import resume_command

    plan = build_plan("multi-task", PRESETS["smoke"], tmp_path)
    train = next(s for s in plan.stages if s.kind == "train")
    assert resume_command(train) == train.command  # nothing written yet: start it
    (train.output / "logs").mkdir(parents=True)
    assert resume_command(train) == train.command and not train.output.exists()  # no checkpoint: start over, cleanly
    config = train.output / "checkpoints" / "last" / "pretrained_model" / "train_config.json"
    config.parent.mkdir(parents=True)
    config.write_text("{}")
    assert resume_command(train) == ("lerobot-train", "--resume=true", f"--config_path={config}")
    merge = next(s for s in plan.stages if s.kind == "merge")
    merge.output.mkdir(parents=True)
    assert resume_command(merge) == (*merge.command, "--overwrite")  # replaces what it half built


def test_executor_ray_runs_collection_and_evaluation_on_ray(tmp_path):
    preset = resolve_preset("smoke", ["executor=ray", "ray_address=head-node:6379"])
    plan = build_plan("single-task", preset, tmp_path)
    outside = [s for s in plan.stages if s.kind in ("collect", "evaluate")]
    assert outside and all(
        "--workers" not in s.command and "--executor" in s.command for s in outside
    )
    for stage in outside:
        at = stage.command.index("--executor")
        assert stage.command[at:at + 4] == ("--executor", "ray", "--ray-address", "head-node:6379")
    local = build_plan("single-task", PRESETS["smoke"], tmp_path)
    assert all("--executor" not in s.command for s in local.stages)
    with pytest.raises(ExperimentError, match="ray_address needs executor=ray"):
        resolve_preset("smoke", ["ray_address=auto"])


def test_the_learning_recipe_evaluates_every_checkpoint_of_its_variations(tmp_path):
    preset = resolve_preset("quick", ["steps=1000", "save_every=500"])
    plan = build_plan("learning", preset, tmp_path / "exp")
    collect, train, *evaluations = plan.stages
    assert collect.command[collect.command.index("--variations") + 1] == "2,3"
    assert "--policy.type=mosaic" in train.command and "--policy.vision_backbone=conv" in train.command
    assert [e.step for e in plan.evaluations] == [500, 1000] and [e.final for e in plan.evaluations] == [False, True]
    assert all(s.command[s.command.index("--variations") + 1] == "2,3" for s in evaluations)
    assert {e.table for e in plan.evaluations} == {"learning"}


def test_train_options_go_to_every_run_and_a_variant_overrides_them(tmp_path):
    preset = resolve_preset("quick", ["train_options=--policy.action_chunk=10 --dataset.episodes=[0,1]",
                                      "ablation_variants=paper,no_action_chunk"])
    plan = build_plan("ablations", preset, tmp_path / "exp")
    runs = {s.key.split("/")[3]: list(s.command) for s in plan.stages if s.kind == "train"}
    assert set(runs) == {"paper", "no_action_chunk"}  # only the rows asked for
    assert runs["paper"][-2:] == ["--policy.action_chunk=10", "--dataset.episodes=[0,1]"]
    chunk = [a for a in runs["no_action_chunk"] if a.startswith("--policy.action_chunk=")]
    assert chunk == ["--policy.action_chunk=10", "--policy.action_chunk=1"]  # the variant's comes last and wins


def test_mosaic_options_go_to_new_mosaic_models_only(tmp_path):
    preset = resolve_preset("smoke", ["mosaic_options=--policy.demo_summary=true", "methods=mosaic,mlp_osil",
                                      "ablation_variants=paper,chunk_10"])
    single = build_plan("single-task", preset, tmp_path / "single")
    trained = {s.key: s.command for s in single.stages if s.kind == "train"}
    assert [key for key, command in trained.items() if "--policy.demo_summary=true" in command] == [
        key for key in trained if "/mosaic/" in key
    ] != []
    ablations = build_plan("ablations", preset, tmp_path / "ablations")
    assert all("--policy.demo_summary=true" not in s.command for s in ablations.stages)  # the paper's MOSAIC
    fine_tune = build_plan("fine-tune", preset, tmp_path / "fine")
    for stage in (s for s in fine_tune.stages if s.kind == "train"):
        from_checkpoint = any(a.startswith("--policy.path=") for a in stage.command)
        assert ("--policy.demo_summary=true" in stage.command) is not from_checkpoint  # kept in its config.json


def test_cpu_preset_trains_mosaic_with_the_combination_that_finishes_the_door(tmp_path):
    plan = build_plan("learning", PRESETS["cpu"], tmp_path / "learning")
    (train,) = [s for s in plan.stages if s.kind == "train"]
    for option in ("--policy.demo_summary=true", "--policy.variation_loss_weight=20",
                   "--policy.hand_relative_targets=true", "--policy.action_chunk=10", "--steps=2250"):
        assert option in train.command
    evaluations = [s for s in plan.stages if s.kind == "evaluate"]
    assert len(evaluations) == 3  # the learning curve: 750, 1500, 2250
    assert all(s.command[s.command.index("--episodes-per-variation") + 1] == "20" for s in evaluations)
    single = build_plan("single-task", PRESETS["cpu"], tmp_path / "single", tasks=("door",))
    baselines = [s for s in single.stages if s.kind == "train" and "/mosaic/" not in s.key]
    assert len(baselines) == 4 and all("--policy.hand_relative_targets=true" not in s.command for s in baselines)


def test_action_noise_goes_to_the_panda_collection_only(tmp_path):
    plan = build_plan("learning", resolve_preset("smoke", ["action_noise=0.005"]), tmp_path / "exp")
    collects = {s.key: s.command for s in plan.stages if s.kind == "collect"}
    panda, sawyer = collects["collect/door"], collects["collect/door_sawyer"]
    assert panda[panda.index("--robot") + 1] == "panda" and panda[panda.index("--action-noise") + 1] == "0.005"
    assert sawyer[sawyer.index("--robot") + 1] == "sawyer" and "--action-noise" not in sawyer
    assert "--variations" not in panda + sawyer
    train = next(s.command for s in plan.stages if s.kind == "train")
    data = tmp_path / "exp" / "data" / "mosaic"
    assert f"--dataset.root={data / 'door_panda'}" in train and f"--policy.demo_root={data / 'door_sawyer'}" in train
    clean = build_plan("learning", resolve_preset("smoke", []), tmp_path / "clean")
    (collect,) = [s.command for s in clean.stages if s.kind == "collect"]
    assert collect[collect.index("--robot") + 1] == "both" and "--action-noise" not in collect


@pytest.mark.parametrize(
    "override, message",
    [
        ("variations=1,7", "door has variations 0-3"),
        ("variations=1,1", "give distinct variation numbers"),
        ("ablation_variants=paper,chunk_99", "unknown chunk_99: choose from paper"),
        ("train_options=policy.action_chunk=10", "give lerobot-train options"),
        ("mosaic_options=policy.demo_summary=true", "preset mosaic_options='policy.demo_summary=true': give"),
        ("action_noise=5", "metres, not millimetres"),
        ("learning_methods=act", "preset learning_methods act: choose from mosaic"),
    ],
)
def test_bad_learning_settings_give_one_clear_line(override, message, tmp_path):
    recipe = "ablations" if override.startswith("ablation") else "learning"
    result = subprocess.run([*EXPERIMENT, "run", recipe, "--preset", "quick", "--set", override, "--dry-run"],
                            capture_output=True, text=True, cwd=tmp_path)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], result.stderr


def test_the_report_names_the_training_options_of_its_preset():
    from pipelines.experiments.report import settings_text

    text = settings_text("cpu", PRESETS["cpu"], [])
    assert "lerobot-train options of every run: `--policy.action_chunk=10`." in text
    assert ("Of MOSAIC's runs (not the ablations' rows): `--policy.demo_summary=true "
            "--policy.variation_loss_weight=20 --policy.hand_relative_targets=true --policy.n_mixtures=1 "
            "--policy.wrong_demo_loss_weight=10 --policy.temporal_ensemble_coeff=0.01 "
            "--policy.weight_average_decay=0.998`.") in text
    assert "Of MOSAIC's runs" not in settings_text("quick", PRESETS["quick"], [])
    with_summary = resolve_preset("quick", ["mosaic_options=--policy.demo_summary=true"])
    assert "Of MOSAIC's runs (not the ablations' rows): `--policy.demo_summary=true`." in settings_text(
        "quick", with_summary, []
    )
    assert "options" not in settings_text("paper", PRESETS["paper"], [])
