"""The paper's experiments (section V and the appendix) as plans of stages.

Each recipe turns (preset, tasks, seeds, output folder) into the same list of stages every time:

- ``single-task``: per task, every method trained on that task's variations (2 attention layers), evaluated on it
  (Table I, "single" rows);
- ``multi-task``: one model per method on all tasks (merged datasets, 3 attention layers, balanced loss),
  evaluated per task (Table I, "multi" rows);
- ``novel-task``: per held-out task, a model trained on the other tasks, evaluated one-shot on the held-out one
  (Table II, "Novel-task");
- ``fine-tune``: those models fine-tuned on the held-out task with a fraction of its data, against training from
  scratch on the same fraction; every saved checkpoint is evaluated (the fine-tuning figure, Table II "Fine-tune");
- ``ablations``: MOSAIC with one option changed at a time (the appendix tables and this project's own options,
  the levers of learning on a CPU among them; ``--set ablation_variants=paper,chunk_10`` picks rows);
- ``learning``: one method on one task, every saved checkpoint evaluated: the learning curve, per-variation
  success and the confusion matrix (with the ``quick`` preset, a training idea tried in minutes).

A plan also lists its :class:`Evaluation` entries: where each evaluation's results land and which table cell it
feeds, which is all :mod:`.report` needs.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from mosaic_data.tasks.spec import TASK_NAMES, VARIATIONS

from .presets import ExperimentError, ExperimentPreset, check_tasks, saved_steps
from .stages import Stage

TRAIN_SEED_BASE = 1000
"""Training seed of seed number s (1-based): 1000 + s. Evaluation always uses mosaic-eval's held-out instances."""

MULTI_TASK_OPTIONS: dict[str, tuple[str, ...]] = {
    "mosaic": ("--policy.n_attention_layers=3",),
    "tosil": ("--policy.n_attention_layers=3",),
}
"""The paper's multi-task model sizes: 3 attention layers instead of 2. The other baselines keep their sizes."""

ABLATIONS: dict[str, tuple[str, tuple[str, ...]]] = {
    "paper": ("MOSAIC as in the paper", ()),
    "contrastive_off": ("contrastive placement", ("--policy.contrastive=off",)),
    "contrastive_before": ("contrastive placement", ("--policy.contrastive=before",)),
    "contrastive_after": ("contrastive placement", ("--policy.contrastive=after",)),
    "positive_fixed": ("contrastive positive", ("--policy.contrastive_positive=fixed",)),
    "positive_same": ("contrastive positive", ("--policy.contrastive_positive=same",)),
    "byol": ("contrastive objective", ("--policy.contrastive_objective=byol",)),
    "attention_full": ("attention pattern", ("--policy.attention_pattern=full",)),
    "with_state": ("this project: robot state input", ("--policy.use_state=true",)),
    "no_action_chunk": ("this project: action chunking", ("--policy.action_chunk=1",)),
    "chunk_10": ("this project: action chunking", ("--policy.action_chunk=10",)),
    "chunk_15": ("this project: action chunking", ("--policy.action_chunk=15",)),
    "temporal_ensemble": ("this project: action chunking", ("--policy.temporal_ensemble_coeff=0.01",)),
    "chunk_10_ensemble": (
        "this project: action chunking", ("--policy.action_chunk=10", "--policy.temporal_ensemble_coeff=0.01"),
    ),
    "gripper_state": (
        "this project: robot state input", ("--policy.use_state=true", "--policy.state_components=[gripper_opening]"),
    ),
    "frame_stride_1": ("this project: time scale", ("--policy.frame_stride=1",)),
    "demo_summary": ("this project: ordered demonstration summary", ("--policy.demo_summary=true",)),
    "lr_cosine": ("this project: learning-rate schedule", ("--policy.lr_schedule=cosine",)),
    "variation_loss": (
        "this project: demonstrations grouped by variation", ("--policy.variation_loss_weight=20",),
    ),
    "hand_relative": ("this project: position targets relative to the hand", ("--policy.hand_relative_targets=true",)),
    "wrong_demo": (
        "this project: actions a wrong demonstration must not explain", ("--policy.wrong_demo_loss_weight=10",),
    ),
    "wrong_demo_nearest": (
        "this project: actions a wrong demonstration must not explain",
        ("--policy.wrong_demo_loss_weight=10", "--policy.wrong_demo_partner=nearest"),
    ),
    "weight_average": ("this project: acting with averaged weights", ("--policy.weight_average_decay=0.998",)),
    "one_mixture": ("this project: one logistic per action dimension", ("--policy.n_mixtures=1",)),
    "one_mixture_wrong_demo": (
        "this project: one logistic per action dimension that a wrong demonstration must not explain",
        ("--policy.n_mixtures=1", "--policy.wrong_demo_loss_weight=10"),
    ),
    "demo_mixture_weights": (
        "this project: mixture weights set by the demonstration",
        ("--policy.demo_summary=true", "--policy.mixture_weights=demo"),
    ),
}
"""Variant name -> (group, lerobot-train options). ``paper`` is the reference row (contrastive both, window
positive, InfoNCE, MOSAIC's attention, images only, 5-step action chunks, 5-frame stride, constant learning rate)."""


@dataclass(frozen=True)
class Evaluation:
    """One mosaic-eval results file and the report cell it feeds."""

    table: str  # single-task | multi-task | novel-task | fine-tune | ablations
    row: str  # method or ablation variant
    task: str  # the column
    seed: int
    step: int
    final: bool  # among the last checkpoints the table's cells average (the curve uses every step)
    results: Path
    fraction: int | None = None  # fine-tune: % of the held-out task's data
    mode: str | None = None  # fine-tune: "fine-tune" or "scratch"


@dataclass
class Plan:
    recipe: str
    stages: list[Stage] = field(default_factory=list)
    evaluations: list[Evaluation] = field(default_factory=list)

    def add(self, stage: Stage) -> Stage:
        if all(existing.key != stage.key for existing in self.stages):
            self.stages.append(stage)
        return stage


@dataclass(frozen=True)
class DataPair:
    """The agent (Panda) and demonstrator (Sawyer) datasets a model trains on."""

    agent_repo: str
    agent_root: Path
    demo_repo: str
    demo_root: Path
    tasks: tuple[str, ...]


def _run_of(checkpoint: Path) -> str:
    """``.../runs/novel-task/door/mosaic/seed1/train/checkpoints/000002/pretrained_model`` -> the run and step."""
    parts = checkpoint.parts
    runs = len(parts) - 1 - parts[::-1].index("runs")
    return "/".join(parts[runs + 1 : -4]) + f" step {int(parts[-2])}"


class PlanBuilder:
    """Stages shared by recipes: collection, merging, training, evaluation of a run's checkpoints."""

    def __init__(self, recipe: str, preset: ExperimentPreset, output_dir: Path, data_dir: Path):
        self.preset = preset
        self.output_dir = Path(output_dir)
        self.data_dir = Path(data_dir)
        self.plan = Plan(recipe)

    # data
    def dataset(self, task: str) -> DataPair:
        """The task's dataset pair, collected by one stage, or two with ``action_noise``.

        DART noise is for the agent's data only: the Sawyer's videos are what the policy is shown, and at
        evaluation they are clean expert demonstrations, so with noise the Panda (``collect/<task>``, perturbed)
        and the Sawyer (``collect/<task>_sawyer``, clean) are collected apart.
        """
        p = self.preset
        check_variations(task, p.variations)
        selection = ("--variations", ",".join(map(str, p.variations))) if p.variations else ()
        which = f"{p.episodes} episodes per variation" + (
            f", variations {','.join(map(str, p.variations))}" if p.variations else "")
        # (stage key, --robot, the dataset the stage is done by, options, title)
        collections = ([(f"collect/{task}", "panda", "panda", ("--action-noise", p.action_noise),
                         f"Panda with action noise {p.action_noise}"),
                        (f"collect/{task}_sawyer", "sawyer", "sawyer", (), "Sawyer")] if p.action_noise
                       else [(f"collect/{task}", "both", "panda", (), "Panda and Sawyer")])
        for key, robot, made, noise, robots in collections:
            self.plan.add(Stage(
                key=key, kind="collect", output=self.data_dir / "mosaic" / f"{task}_{made}",
                title=f"collect {task} ({robots}, {which})",
                command=("mosaic-data", "collect", "--task", task, "--robot", robot, "--episodes", str(p.episodes),
                         "--image-size", p.image_size, *selection, *noise, *executor_args(p), "--output-dir",
                         str(self.data_dir), "--quiet"),
            ))
        return DataPair(f"mosaic/{task}_panda", self.data_dir / "mosaic" / f"{task}_panda",
                        f"mosaic/{task}_sawyer", self.data_dir / "mosaic" / f"{task}_sawyer", (task,))

    def merged(self, tasks: tuple[str, ...]) -> DataPair:
        """One dataset per robot holding ``tasks`` (LeRobot's aggregation through ``mosaic-data merge``)."""
        if len(tasks) == 1:
            return self.dataset(tasks[0])
        for task in tasks:
            self.dataset(task)
        name = "all" if set(tasks) == set(TASK_NAMES) else "-".join(tasks)
        roots = {}
        for robot in ("panda", "sawyer"):
            repo = f"mosaic/merged_{name}_{robot}"
            roots[robot] = (repo, self.data_dir / repo)
            self.plan.add(Stage(
                key=f"merge/{name}_{robot}", kind="merge", output=self.data_dir / repo,
                title=f"merge {', '.join(tasks)} ({robot})",
                command=("mosaic-data", "merge", "--repo-id", repo, "--output-dir", str(self.data_dir),
                         *(str(self.data_dir / "mosaic" / f"{task}_{robot}") for task in tasks)),
            ))
        return DataPair(*roots["panda"], *roots["sawyer"], tasks)

    # training
    def train(self, run: str, data: DataPair, method: str, seed: int, options: tuple[str, ...] = (),
              steps: int | None = None, save_every: int | None = None, init_from: Path | None = None,
              episodes: list[int] | None = None, paper_model: bool = False) -> Path:
        """A lerobot-train stage; the run folder. ``init_from`` fine-tunes that checkpoint instead of a new model.

        A new MOSAIC model gets the preset's ``mosaic_options`` unless ``paper_model`` (the ablations' rows).
        """
        p = self.preset
        steps, save_every = steps or p.steps, save_every or p.save_every
        train_dir = self.output_dir / "runs" / run / "train"
        # A fine-tuned model keeps its checkpoint's trunk (config.json); a new one gets the preset's.
        source = ((f"--policy.path={init_from}",) if init_from
                  else (f"--policy.type={method}", f"--policy.vision_backbone={p.vision_backbone}"))
        own = p.mosaic_options if method == "mosaic" and not init_from and not paper_model else ()
        selection = (f"--dataset.episodes=[{','.join(map(str, episodes))}]",) if episodes is not None else ()
        self.plan.add(Stage(
            key=f"train/{run}", kind="train", output=train_dir,
            title=f"train {run} ({steps} steps{', from ' + _run_of(init_from) if init_from else ''})",
            command=("lerobot-train", *source,
                     f"--dataset.repo_id={data.agent_repo}", f"--dataset.root={data.agent_root}", *selection,
                     f"--policy.demo_repo_id={data.demo_repo}", f"--policy.demo_root={data.demo_root}",
                     f"--policy.train_obs_frames={p.train_obs_frames}", "--policy.push_to_hub=false",
                     f"--policy.device={p.device}", f"--batch_size={p.batch_size}", f"--steps={steps}",
                     f"--save_freq={save_every}", "--log_freq=50", f"--num_workers={p.num_workers}",
                     f"--seed={TRAIN_SEED_BASE + seed}", f"--output_dir={train_dir}", *p.train_options, *own, *options),
        ))
        return train_dir

    # evaluation
    def evaluate(self, table: str, row: str, run: str, train_dir: Path, tasks: tuple[str, ...], seed: int,
                 steps: int | None = None, save_every: int | None = None, every_checkpoint: bool = False,
                 **cell: object) -> None:
        """mosaic-eval stages for the last ``eval_checkpoints`` saved checkpoints (or all) on each task."""
        p = self.preset
        steps, save_every = steps or p.steps, save_every or p.save_every
        saved = saved_steps(steps, save_every)
        final = saved[-p.eval_checkpoints:]
        for step in saved if every_checkpoint else final:
            checkpoint = train_dir / "checkpoints" / f"{step:0{max(6, len(str(steps)))}d}" / "pretrained_model"
            for task in tasks:
                results = self.output_dir / "runs" / run / "eval" / f"step_{step:06d}" / task / "results.json"
                command = ["mosaic-eval", f"--policy.path={checkpoint}", "--task", task,
                           "--episodes-per-variation", str(p.eval_episodes), *executor_args(p),
                           "--output", str(results), "--quiet"]
                if p.eval_max_steps:
                    command += ["--max-steps", str(p.eval_max_steps)]
                if p.variations:
                    command += ["--variations", ",".join(map(str, p.variations))]
                self.plan.add(Stage(
                    key=f"eval/{run}/step_{step:06d}/{task}", kind="evaluate", output=results,
                    title=f"evaluate {run} step {step} on {task}", command=tuple(command),
                ))
                self.plan.evaluations.append(Evaluation(
                    table=table, row=row, task=task, seed=seed, step=step, final=step in final, results=results,
                    **cell,  # type: ignore[arg-type]
                ))


def check_variations(task: str, variations: tuple[int, ...]) -> None:
    """ExperimentError unless every selected variation is one of ``task``'s."""
    count = len(VARIATIONS[task])
    if any(v >= count for v in variations):
        raise ExperimentError(
            f"preset variations={','.join(map(str, variations))}: {task} has variations 0-{count - 1} "
            f"(`mosaic-data tasks` lists them): choose them with --set variations=..."
        )


def episodes_fraction(task: str, episodes_per_variation: int, percent: int) -> list[int]:
    """Episode indices of the first ``percent``% of every variation's episodes in a collected dataset.

    ``mosaic-data collect`` numbers episodes variation by variation, slot by slot (episode = position of the
    variation * episodes per variation + slot), so the selection is known before the data exists; the train stage
    checks it against the dataset's sidecar when it runs.
    """
    keep = max(1, round(episodes_per_variation * percent / 100))
    n_variations = len(VARIATIONS[task])
    return [v * episodes_per_variation + slot for v in range(n_variations) for slot in range(keep)]


def check_episode_layout(root: Path, task: str, episodes_per_variation: int) -> None:
    """ExperimentError unless the dataset at ``root`` numbers its episodes as :func:`episodes_fraction` assumes."""
    from mosaic_data.collection.metadata import read_sidecar

    sidecar = read_sidecar(root)
    records = (sidecar or {}).get("episodes", [])
    positions = {v: i for i, v in enumerate(sorted({r["variation"] for r in records}))}
    expected = len(VARIATIONS[task]) * episodes_per_variation
    if len(records) != expected or any(
        r["episode_index"] != positions[r["variation"]] * episodes_per_variation + r["slot"] for r in records
    ):
        raise ExperimentError(
            f"{root} is not the dataset this plan selects fractions of ({expected} episodes of {task}, numbered "
            "variation by variation): collect it again with `mosaic-data collect` into an empty --data-dir"
        )


def _seeds(preset: ExperimentPreset) -> range:
    return range(1, preset.seeds + 1)


def _trained_per_task(b: PlanBuilder, tasks: tuple[str, ...], table: str, methods: tuple[str, ...],
                      every_checkpoint: bool = False) -> None:
    """Per task: each method trained on the task's dataset and evaluated on it."""
    for task in tasks:
        data = b.dataset(task)
        for method in methods:
            for seed in _seeds(b.preset):
                run = f"{table}/{task}/{method}/seed{seed}"
                train_dir = b.train(run, data, method, seed)
                b.evaluate(table, method, run, train_dir, (task,), seed, every_checkpoint=every_checkpoint)


def single_task(b: PlanBuilder, tasks: tuple[str, ...]) -> None:
    _trained_per_task(b, tasks, "single-task", b.preset.methods)


def multi_task(b: PlanBuilder, tasks: tuple[str, ...]) -> None:
    data = b.merged(tasks)
    for method in b.preset.methods:
        for seed in _seeds(b.preset):
            run = f"multi-task/{data.agent_repo.split('/')[1].removesuffix('_panda')}/{method}/seed{seed}"
            train_dir = b.train(run, data, method, seed, MULTI_TASK_OPTIONS.get(method, ()))
            b.evaluate("multi-task", method, run, train_dir, tasks, seed)


def _pool(b: PlanBuilder, held_out: str) -> tuple[str, ...]:
    pool = tuple(task for task in b.preset.novel_task_pool if task != held_out)
    if not pool:
        raise ExperimentError(
            f"no task left to train a novel-task model for {held_out}: add tasks to the pool (--set novel_task_pool=...)"
        )
    return pool


def _novel_run(b: PlanBuilder, held_out: str, method: str, seed: int) -> tuple[str, Path]:
    data = b.merged(_pool(b, held_out))
    run = f"novel-task/{held_out}/{method}/seed{seed}"
    return run, b.train(run, data, method, seed, MULTI_TASK_OPTIONS.get(method, ()))


def novel_task(b: PlanBuilder, tasks: tuple[str, ...]) -> None:
    for held_out in tasks:
        for method in b.preset.methods:
            for seed in _seeds(b.preset):
                run, train_dir = _novel_run(b, held_out, method, seed)
                b.evaluate("novel-task", method, run, train_dir, (held_out,), seed)


def fine_tune(b: PlanBuilder, tasks: tuple[str, ...]) -> None:
    p = b.preset
    for held_out in tasks:
        target = b.dataset(held_out)
        for method in p.fine_tune_methods:
            for seed in _seeds(p):
                novel, novel_dir = _novel_run(b, held_out, method, seed)
                # where fine-tuning starts: the novel-task model on the held-out task (Table II, Novel-task)
                b.evaluate("novel-task", method, novel, novel_dir, (held_out,), seed)
                last = novel_dir / "checkpoints" / f"{p.steps:0{max(6, len(str(p.steps)))}d}" / "pretrained_model"
                for fraction in p.fine_tune_fractions:
                    episodes = episodes_fraction(held_out, p.episodes, fraction)
                    for mode in ("fine-tune", "scratch"):
                        run = f"fine-tune/{held_out}/{method}/{mode}-{fraction}/seed{seed}"
                        # from scratch: the novel-task model's architecture; fine-tuning inherits it from the checkpoint
                        options = MULTI_TASK_OPTIONS.get(method, ()) if mode == "scratch" else ()
                        train_dir = b.train(run, target, method, seed, options, steps=p.fine_tune_steps,
                                            save_every=p.fine_tune_save_every,
                                            init_from=last if mode == "fine-tune" else None, episodes=episodes)
                        b.evaluate("fine-tune", method, run, train_dir, (held_out,), seed, steps=p.fine_tune_steps,
                                   save_every=p.fine_tune_save_every, every_checkpoint=True,
                                   fraction=fraction, mode=mode)


def ablation_variants(preset: ExperimentPreset) -> tuple[str, ...]:
    """The rows the preset asks for, in ABLATIONS' order (all of them when it names none)."""
    unknown = [v for v in preset.ablation_variants if v not in ABLATIONS]
    if unknown:
        raise ExperimentError(f"preset ablation_variants: unknown {', '.join(unknown)}: choose from {', '.join(ABLATIONS)}")
    return tuple(v for v in ABLATIONS if v in preset.ablation_variants or not preset.ablation_variants)


def ablations(b: PlanBuilder, tasks: tuple[str, ...]) -> None:
    variants = ablation_variants(b.preset)
    for task in tasks:
        data = b.dataset(task)
        for variant in variants:
            options = ABLATIONS[variant][1]
            for seed in _seeds(b.preset):
                run = f"ablations/{task}/{variant}/seed{seed}"
                train_dir = b.train(run, data, "mosaic", seed, options, paper_model=True)
                b.evaluate("ablations", variant, run, train_dir, (task,), seed)


def learning(b: PlanBuilder, tasks: tuple[str, ...]) -> None:
    _trained_per_task(b, tasks, "learning", b.preset.learning_methods, every_checkpoint=True)


RECIPES = {
    "single-task": (single_task, "single_task_tasks", "Table I, single-task rows: each method trained and evaluated per task"),
    "multi-task": (multi_task, "multi_task_tasks", "Table I, multi-task rows: one model per method on all tasks"),
    "novel-task": (novel_task, "novel_task_tasks", "Table II, Novel-task: trained on the other tasks, one-shot on a new one"),
    "fine-tune": (fine_tune, "fine_tune_tasks", "Table II, Fine-tune, and the fine-tuning figure: novel-task models fine-tuned on 25-100% of the new task's data vs training from scratch"),
    "ablations": (ablations, "ablation_tasks", "Appendix: contrastive placement, positive, BYOL, attention pattern, state input, action chunking, time scale"),
    "learning": (learning, "learning_tasks", "One method on one task, every checkpoint evaluated: learning curve, per-variation success, confusion"),
}
"""Recipe name -> (plan function, the preset field with its default tasks, what it reproduces)."""


def build_plan(recipe: str, preset: ExperimentPreset, output_dir: Path, data_dir: Path | None = None,
               tasks: tuple[str, ...] | None = None) -> Plan:
    """The recipe's stages, in run order; the same arguments always give the same stages and commands."""
    if recipe not in RECIPES:
        raise ExperimentError(f"unknown recipe {recipe!r}: choose one of {', '.join(RECIPES)} (see `mosaic-experiment list`)")
    function, tasks_field, _ = RECIPES[recipe]
    tasks = check_tasks(tasks) if tasks is not None else getattr(preset, tasks_field)
    output_dir = Path(output_dir).absolute()
    builder = PlanBuilder(recipe, preset, output_dir, Path(data_dir).absolute() if data_dir else output_dir / "data")
    function(builder, tuple(tasks))
    return builder.plan


def executor_args(p: ExperimentPreset) -> tuple[str, ...]:
    """How a collect or evaluate stage runs: ``workers`` local processes, or Ray tasks on every CPU of the cluster."""
    if p.executor == "ray":
        return ("--executor", "ray", *(("--ray-address", p.ray_address) if p.ray_address else ()))
    return ("--workers", str(p.workers))
