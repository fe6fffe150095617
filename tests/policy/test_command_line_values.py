"""Option values as lerobot-train's command line delivers them (draccus reads each value as YAML)."""

from __future__ import annotations

import draccus
import yaml
import pytest

from mosaic_policy.mosaic.configuration_mosaic import MosaicConfig
from pipelines.experiments.recipes import ABLATIONS


@pytest.mark.parametrize("variant", list(ABLATIONS))
def test_every_ablation_option_reaches_the_config(variant):
    """Every ablation's options parse into the config, `--policy.contrastive=off` included (YAML reads `off` as
    false, which the config takes as "off")."""
    _, options = ABLATIONS[variant]
    config = draccus.parse(config_class=MosaicConfig, args=[o.replace("--policy.", "--") for o in options])
    for option in options:
        name, value = option.removeprefix("--policy.").split("=")
        expected = "off" if value == "off" else yaml.safe_load(value)  # as draccus reads a value: YAML
        assert getattr(config, name) == expected


@pytest.mark.parametrize("backbone", ["resnet18", "conv"])
def test_vision_backbone_reaches_the_config(backbone):
    config = draccus.parse(config_class=MosaicConfig, args=[f"--vision_backbone={backbone}"])
    assert config.vision_backbone == backbone


def test_a_bad_vision_backbone_on_the_command_line_is_one_line_naming_the_choices(capsys):
    """A Literal field: the parser itself refuses the value (a failing __post_init__ would only tell lerobot-train's
    user "Couldn't instantiate class MosaicConfig")."""
    with pytest.raises(SystemExit):
        draccus.parse(config_class=MosaicConfig, args=["--vision_backbone=resnet50"])
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert "--vision_backbone: invalid choice: 'resnet50' (choose from 'resnet18', 'conv')" in error


@pytest.mark.parametrize(
    "args, message",
    [
        (["--vision_backbone=conv", "--conv_channels=100"], "`conv_channels` must be a multiple of 8"),
        (["--vision_backbone=resnet18", "--conv_channels=128"], "pass --policy.vision_backbone=conv with it"),
        (["--vision_backbone=conv", "--conv_keypoints=128"], "fill fewer than the 256 `conv_channels`"),
        (["--vision_backbone=resnet18", "--conv_keypoints=16"], "the resnet18 trunk has none"),
    ],
)
def test_a_conv_width_that_cannot_be_built_is_refused_naming_the_fix(args, message):
    """The conv trunk's width is the attention's: a multiple of 8 (heads, sinusoidal encodings), and only the conv
    trunk has one to set."""
    with pytest.raises(draccus.utils.ParsingError) as error:
        draccus.parse(config_class=MosaicConfig, args=args)
    assert message in str(error.value.__cause__ or error.value.__context__)


def test_the_conv_width_reaches_the_config():
    config = draccus.parse(config_class=MosaicConfig, args=["--vision_backbone=conv", "--conv_channels=128"])
    assert (config.vision_backbone, config.conv_channels) == ("conv", 128)


def test_a_bad_learning_rate_schedule_on_the_command_line_is_one_line_naming_the_choices(capsys):
    with pytest.raises(SystemExit):
        draccus.parse(config_class=MosaicConfig, args=["--lr_schedule=linear"])
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert "--lr_schedule: invalid choice: 'linear' (choose from 'constant', 'cosine')" in error


def test_the_learning_rate_schedule_reaches_the_scheduler_preset():
    config = draccus.parse(config_class=MosaicConfig, args=["--lr_schedule=cosine", "--lr_final_ratio=0.2"])
    preset = config.get_scheduler_preset()
    assert (preset.schedule, preset.final_lr_ratio) == ("cosine", 0.2)
