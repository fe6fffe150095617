"""`mosaic-eval --rerun`: compressed images, columns of scalars, a real-time ``time`` timeline, and the size goal
of at most 1 MB per 100-step episode with attention (no RGBA overlays at frame size)."""

from __future__ import annotations

import numpy as np
from tests.helpers.evaluation import write_tiny_checkpoint
from tests.helpers.recordings import rows_per_entity

from mosaic_data.collection.schema import FPS
from pipelines.evaluation.cli import main as mosaic_eval

BYTES_PER_STEP = 10_000
"""1 MB per 100 steps: what one step of the recording (agent frame, demo frame, 5 attention maps, curves) may take."""


def _chunks(path):
    from rerun.experimental import RrdReader

    return [(chunk.entity_path, chunk.is_static, chunk.to_record_batch().to_pydict()) for chunk in RrdReader(path).store().stream()]


def test_recording_at_paper_size_stays_under_1mb_per_100_steps_and_plays_at_20hz(tmp_path):
    checkpoint = write_tiny_checkpoint(tmp_path / "checkpoint", height=100, width=180)  # the paper's camera
    recording = tmp_path / "eval.rrd"
    code = mosaic_eval([
        f"--policy.path={checkpoint}", "--task", "door", "--variations", "1", "--episodes-per-variation", "2",
        "--rerun-episodes", "2", "--workers", "1", "--max-steps", "20", "--rerun", str(recording),
        "--output", str(tmp_path / "results.json"), "--quiet",
    ])
    assert code == 0

    rows = rows_per_entity(recording)
    assert rows["/agent/camera"] == rows["/action/x"] == rows["/agent/camera/attention"] == 2 * 20
    chunks = _chunks(recording)
    eval_steps = sorted({s for entity, static, d in chunks if not static for s in d.get("eval_step", [])})
    assert eval_steps == list(range(len(eval_steps))), "one eval_step per recorded step, episodes back to back"
    size = recording.stat().st_size
    assert size <= BYTES_PER_STEP * len(eval_steps), f"{size} bytes for {len(eval_steps)} steps"

    columns = {name for entity, static, d in chunks for name in (f"{entity}:{key}" for key in d)}
    for entity in ("/agent/camera", "/demo/video", "/demo/used/0"):
        assert f"{entity}:EncodedImage:blob" in columns and f"{entity}:Image:buffer" not in columns, entity
    assert "/action/x:SeriesLines:names" in columns and "/attention_on_demo/layer_1:SeriesLines:names" in columns

    # the attention maps stay at the token grid and are stretched over the frame by a static transform
    (scale,) = [d["Transform3D:scale"][0][0] for entity, static, d in chunks if entity == "/agent/camera/attention" and static
                and "Transform3D:scale" in d]
    (image_format,) = [d["Image:format"][0][0] for entity, static, d in chunks if entity == "/agent/camera/attention" and static
                       and "Image:format" in d]
    assert (image_format["width"], image_format["height"]) == (12, 7)  # the trunk's token grid at 100x180
    np.testing.assert_allclose([image_format["width"] * scale[0], image_format["height"] * scale[1]], [180, 100], rtol=1e-6)

    # time = eval_step / 20 Hz on every temporal row; step restarts with each episode
    for entity, static, d in chunks:
        if static or "time" not in d:
            continue
        seconds = np.array([t.total_seconds() for t in d["time"]])
        np.testing.assert_allclose(seconds, np.array(d["eval_step"]) / FPS, atol=1e-6, err_msg=entity)
    agent = [d for entity, static, d in chunks if entity == "/agent/camera" and not static]
    steps_by_episode: dict[int, list[int]] = {}
    for d in agent:
        for episode, step in zip(d["episode"], d["step"]):
            steps_by_episode.setdefault(episode, []).append(step)
    assert {e: sorted(s) for e, s in steps_by_episode.items()} == {0: list(range(20)), 1: list(range(20))}
