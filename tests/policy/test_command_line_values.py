"""Option values as lerobot-train's command line delivers them (draccus reads each value as YAML)."""

from __future__ import annotations

import draccus
import pytest

from mosaic_policy.mosaic.configuration_mosaic import MosaicConfig
from pipelines.experiments.recipes import ABLATIONS


@pytest.mark.parametrize("variant", list(ABLATIONS))
def test_every_ablation_option_reaches_the_config(variant):
    """`--policy.contrastive=off` used to fail: YAML reads `off` as false, and the config refused False."""
    _, options = ABLATIONS[variant]
    config = draccus.parse(config_class=MosaicConfig, args=[o.replace("--policy.", "--") for o in options])
    for option in options:
        name, value = option.removeprefix("--policy.").split("=")
        expected = {"true": True, "false": False}.get(value, int(value) if value.isdigit() else value)
        assert getattr(config, name) == expected
