"""Fixtures of the evaluation tests: small untrained MOSAIC and ACT checkpoints, written once per session."""

import pytest

from tests.helpers.evaluation import write_tiny_act_checkpoint, write_tiny_checkpoint


@pytest.fixture(scope="session")
def tiny_checkpoint(tmp_path_factory):
    return write_tiny_checkpoint(tmp_path_factory.mktemp("checkpoint") / "pretrained_model")


@pytest.fixture(scope="session")
def tiny_act_checkpoint(tmp_path_factory):
    return write_tiny_act_checkpoint(tmp_path_factory.mktemp("act_checkpoint") / "pretrained_model")
