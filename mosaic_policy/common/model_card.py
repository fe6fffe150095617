"""The model card of a pushed demo-conditioned policy (``README.md`` of its Hub repo): MOSAIC or a baseline.

LeRobot's generic card tells a reader to run the policy with ``lerobot-rollout --robot.type=<robot>`` on a
real robot and says nothing of what these policies need: the ``lerobot_policy_mosaic`` plugin (without it
LeRobot does not know ``type: mosaic``, ``tosil``, ...), and one demonstration video per episode. This card says
how to install the plugin, what the demonstration input is, and how to train and evaluate the policy in the
simulated suite (``mosaic-eval``, ``lerobot-eval --env.type=mosaic``). LeRobot's ``push_model_to_hub`` calls
the policy's ``generate_model_card``, which renders :data:`MODEL_CARD_TEMPLATE` here.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from huggingface_hub import ModelCard

    from .configuration_demo import DemoConditionedConfig

PAPER_URL = "https://arxiv.org/abs/2110.05455"

INSTALL_COMMAND = "pip install -e . -e plugins/lerobot_policy_mosaic -e plugins/lerobot_env_mosaic"
"""Run in a checkout of the mosaic toolkit: the toolkit, the policy plugin (``--policy.type=mosaic``) and the
environment plugin (``--env.type=mosaic``)."""

MODEL_CARD_TEMPLATE = """---
{{ card_data }}
---

# {{ policy_name }} one-shot imitation policy{% if policy_repo_id %}: {{ policy_repo_id }}{% endif %}

{% if policy_type == "mosaic" %}A [MOSAIC]({{ paper_url }}) policy (*Towards More Generalizable One-shot Visual Imitation Learning*){% else %}A {{ policy_name }} policy, one of the baselines of [MOSAIC]({{ paper_url }})'s Table I,{% endif %} trained
with [LeRobot](https://github.com/huggingface/lerobot) and the `mosaic` toolkit. It acts in the simulated
MOSAIC task suite (robosuite + MuJoCo): a Panda arm does the task variation that **one demonstration video**
shows, a video of a Sawyer arm doing that variation in another scene instance.

## Install

The policy type `{{ policy_type }}` is not part of LeRobot: it comes with the LeRobot plugin `lerobot_policy_mosaic`
of the `mosaic` toolkit, which LeRobot imports at start-up. In a checkout of the toolkit:

```bash
{{ install_command }}
```

(`bash scripts/setup.sh` does the same in a fresh virtual environment). Without the plugin, loading this
policy fails with an unknown policy type `{{ policy_type }}`.

## The demonstration input

Every episode is conditioned on one demonstration of the variation to do: {{ n_demo_frames }} frames of the
demonstrator's camera video `{{ camera_key }}` at {{ image_height }}x{{ image_width }} (H x W) RGB, the same
camera and size as the agent's observations (first frame, last frame and the centre frame of each middle
segment; a longer video is subsampled that way).

```python
from mosaic_policy import policy_class

policy = policy_class("{{ policy_type }}").from_pretrained("{{ policy_path }}")
policy.reset()
policy.set_demo(video)          # (N, H, W, 3) uint8 or (N, 3, H, W) float in [0, 1]: once per episode
action = policy.select_action(batch)   # the current frame under "{{ camera_key }}", every control step
```

`lerobot-eval --env.type=mosaic` delivers the demonstration itself, as the observation `observation.demo`.
The policy is queried every {{ action_chunk }} control steps and hands out the {{ action_chunk }} predicted
absolute end-effector targets in order in between (20 Hz control).

## Evaluate

One-shot rollouts in the simulated suite, each with a fresh Sawyer demonstration of another instance:

```bash
mosaic-eval --policy.path={{ policy_path }} --task {{ eval_task }}
lerobot-eval --policy.path={{ policy_path }} --env.type=mosaic --env.task={{ eval_task }}
```

`mosaic-eval` reports success per variation and which variation the agent did instead (`results.md`).

## Train

An agent (Panda) dataset paired with the demonstrator (Sawyer) dataset of the same variations, both made
by `mosaic-data collect`:

```bash
lerobot-train --policy.type={{ policy_type }} --dataset.repo_id={{ agent_repo_id }} \\
    --policy.demo_repo_id={{ demo_repo_id }} --batch_size=30 --steps=20000
```

`--policy.path={{ policy_path }}` instead of `--policy.type={{ policy_type }}` fine-tunes this policy. The demonstrator
dataset is read from LeRobot's cache (`$HF_LEROBOT_HOME/<demo_repo_id>`) unless `--policy.demo_root` gives
its folder; the saved config keeps no machine-local path.
{% if input_features or output_features %}
## Inputs & outputs

| Feature | Type | Shape |
| --- | --- | --- |
{% for name, feature in input_features.items() %}| `{{ name }}` (input) | {{ feature.type.value }} | `{{ feature.shape }}` |
{% endfor %}| `{{ demo_key }}` (input, once per episode) | VISUAL | `({{ n_demo_frames }}, 3, {{ image_height }}, {{ image_width }})` |
{% for name, feature in output_features.items() %}| `{{ name }}` (output) | {{ feature.type.value }} | `{{ feature.shape }}` |
{% endfor %}
{%- endif %}
## Training data

- **Agent dataset:** `{{ agent_repo_id }}`{% if dataset %} ({{ dataset.episodes }} episodes, {{ dataset.frames }} frames at {{ dataset.fps }} FPS){% endif %}
- **Demonstrator dataset:** `{{ demo_repo_id }}`
{% if tasks %}- **Tasks:** {% for task in tasks %}`{{ task }}`{% if not loop.last %}, {% endif %}{% endfor %}
{% endif %}{% if dataset and dataset.tasks %}- **Variations:** {% for task in dataset.tasks %}"{{ task }}"{% if not loop.last %}, {% endif %}{% endfor %}
{% endif %}{% if training %}
## Training configuration

| Setting | Value |
| --- | --- |
| Training steps | {{ training.steps }} |
| Batch size | {{ training.batch_size }} |
{% if training.optimizer %}| Optimizer | {{ training.optimizer }} |
{% endif %}{% if training.lr %}| Learning rate | {{ training.lr }} |
{% endif %}{% if training.seed is not none %}| Seed | {{ training.seed }} |
{% endif %}| LeRobot version | {{ training.lerobot_version }} |
{% endif %}
## Citation

```bibtex
@inproceedings{mandi2022mosaic,
    title = {Towards More Generalizable One-shot Visual Imitation Learning},
    author = {Mandi, Zhao and Liu, Fangchen and Lee, Kimin and Abbeel, Pieter},
    booktitle = {IEEE International Conference on Robotics and Automation (ICRA)},
    year = {2022}
}
```
"""
"""Jinja template of the card (Hugging Face's ``ModelCard.from_template``); LeRobot's is for real robots."""


def eval_task_option(variations: list[str]) -> str:
    """``--task`` for the evaluation commands: the one task the training variations belong to, else ``all``
    (several tasks), else ``<task>`` (variations not in the suite's table, or none known)."""
    from mosaic_data.tasks.spec import task_of_variation

    table = task_of_variation()
    tasks = {table.get(variation) for variation in variations}
    if not tasks or None in tasks:
        return "<task>"
    return tasks.pop() if len(tasks) == 1 else "all"


def build_model_card(
    config: DemoConditionedConfig,
    image_hw: tuple[int, int],
    dataset_repo_id: str | None,
    card_context: dict[str, Any],
    license: str | None = None,
    tags: list[str] | None = None,
) -> ModelCard:
    """The card of a demo-conditioned policy; ``card_context`` holds LeRobot's template values (training, dataset, ...)."""
    from huggingface_hub import ModelCard, ModelCardData

    from mosaic_data.constants import OBS_DEMO_KEY, POLICY_TYPES
    from mosaic_data.tasks.spec import task_of_variation

    dataset = card_context.get("dataset") or None
    variations = list(dataset["tasks"]) if dataset else []
    datasets = [name for name in (dataset_repo_id, config.demo_repo_id) if name]
    card_data = ModelCardData(
        license=license or "apache-2.0",
        library_name="lerobot",
        pipeline_tag="robotics",
        tags=sorted(set(tags or []) | {"robotics", "lerobot", "mosaic", config.type, "one-shot-imitation", "robosuite"}),
        model_name=config.type,
        datasets=datasets or None,
    )
    table = task_of_variation()
    context = {
        **card_context,
        "paper_url": PAPER_URL,
        "policy_type": config.type,
        "policy_name": POLICY_TYPES.get(config.type, config.type),
        "install_command": INSTALL_COMMAND,
        "policy_repo_id": config.repo_id,
        "policy_path": config.repo_id or "<hf_user>/<policy_repo_id>",
        "agent_repo_id": dataset_repo_id or "<agent dataset, e.g. mosaic/door_panda>",
        "demo_repo_id": config.demo_repo_id or "<demonstrator dataset, e.g. mosaic/door_sawyer>",
        "camera_key": config.camera_key,
        "image_height": image_hw[0],
        "image_width": image_hw[1],
        "n_demo_frames": config.n_demo_frames,
        "action_chunk": config.action_chunk,
        "demo_key": OBS_DEMO_KEY,
        "eval_task": eval_task_option(variations),
        "tasks": sorted({table[v] for v in variations if v in table}),
    }
    # No card.validate(): it asks the Hub over the network; the upload checks the metadata anyway.
    return ModelCard.from_template(card_data, template_str=MODEL_CARD_TEMPLATE, **context)
