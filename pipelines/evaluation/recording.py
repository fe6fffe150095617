"""One rerun recording per evaluation: demonstration, agent camera with the policy's attention, actions, success.

Timelines: ``time`` plays the recorded episodes one after the other in real time (20 Hz, the control rate: the
viewer's default), ``eval_step`` counts the same steps, ``step`` is the step within an episode and ``episode``
jumps between episodes. Per step the recording holds:

* ``/demo/video``: the demonstrator's video, played alongside the rollout (frame ``step`` of it);
* ``/demo/used/<k>``: the demonstration frames the policy conditions on, each with ``attention`` drawn over it:
  where the current observation's queries look in that frame;
* ``/agent/camera`` with ``/agent/camera/attention``: the agent's camera and the attention on its own tokens;
* ``/action/<dim>``, ``/attention_on_demo/layer_<i>`` (share of attention on demo tokens) and ``/success``.

Attention is the chosen layer's weights averaged over heads and query locations, normalised per image (the
hottest token of each frame is fully drawn).

Size: camera frames are stored as JPEG and each attention map at the policy's token grid (e.g. 7x12 for 100x180
frames), stretched over its frame by a static transform and smoothed by the viewer (linear magnification);
a whole episode goes in as a few columns (``send_columns``). A 100-step episode with attention stays under 1 MB
(tested).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mosaic_data.collection.schema import ACTION_NAMES, FPS
from mosaic_data.recording_files import StepTimelines, jpeg_bytes, send_jpegs

from .rollouts import EpisodeResult

TIMELINES = StepTimelines(FPS, counter="eval_step")
"""``time`` at the control rate, ``eval_step`` over all recorded episodes, ``step`` within one."""

ATTENTION_DRAW_ORDER = 10.0
"""Above the camera frame: rerun draws 2D images with a higher draw order on top."""

ATTENTION_OPACITY = 2 / 3
"""Of the hottest token; the overlay's alpha channel scales it down to 0 for the coldest. Set explicitly: with
rerun's default (1.0 over a JPEG frame) the overlay's alpha channel is ignored and the frame is hidden."""


def blueprint(n_demo_frames: int):
    import rerun.blueprint as rrb

    used = [rrb.Spatial2DView(origin=f"/demo/used/{k}", name=f"demo frame {k}") for k in range(n_demo_frames)]
    left = [rrb.Spatial2DView(origin="/demo/video", name="demonstration (demonstrator)")]
    if used:
        left.append(rrb.Grid(*used))
    left.append(rrb.TextDocumentView(origin="/episode", name="episode"))
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(*left),
            rrb.Vertical(
                rrb.Spatial2DView(origin="/agent", name="agent camera + attention on its own tokens"),
                rrb.TimeSeriesView(origin="/action", name="action (target pose, gripper)"),
                rrb.TimeSeriesView(origin="/attention_on_demo", name="attention on the demonstration"),
                rrb.TimeSeriesView(origin="/success", name="success"),
            ),
        ),
        rrb.TimePanel(timeline="time"),
        collapse_panels=True,
    )


class EvaluationRecording:
    """Logs recorded episodes into one .rrd file as they arrive from the workers."""

    def __init__(self, path: Path, n_demo_frames: int, attention_layer: int = -1) -> None:
        import rerun as rr

        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.stream = rr.RecordingStream("mosaic_eval")
        self.stream.save(str(self.path), default_blueprint=blueprint(n_demo_frames))
        self.attention_layer = attention_layer
        self.episodes = 0
        self._global_step = 0
        for name in ACTION_NAMES:
            self.stream.log(f"/action/{name}", rr.SeriesLines(names=name), static=True)
        self.stream.log("/success", rr.SeriesLines(names="success"), static=True)
        self._named_layers = 0
        self._overlay_layout: dict[str, tuple] = {}  # entity -> (token grid, frame size) of its static layout

    def _times(self, count: int) -> list:
        """Index columns of this episode's first ``count`` steps."""
        return TIMELINES.columns(self.episodes, self._global_step, count)

    def _set_time(self, step: int) -> None:
        """Row-wise logging (the episode's text, the conditioning frames) at ``step`` of this episode."""
        TIMELINES.set(self.stream, self.episodes, self._global_step, step)

    def _send_jpegs(self, entity: str, frames) -> None:
        if len(frames):
            send_jpegs(self.stream, entity, frames, self._times(len(frames)))

    def _send_scalars(self, entity: str, values: np.ndarray) -> None:
        import rerun as rr

        if len(values):
            self.stream.send_columns(entity, indexes=self._times(len(values)), columns=rr.Scalars.columns(scalars=values))

    def log_episode(self, result: EpisodeResult) -> None:
        import rerun as rr

        recording = result.recording
        if recording is None:
            return
        steps = max(len(recording.frames), len(recording.demo_video), 1)
        self._set_time(0)
        self.stream.log("/episode", rr.TextDocument(
            f"**{result.agent}** on {result.task} variation {result.variation}: {result.description}\n\n"
            f"agent instance seed {result.seed}, demonstration seed {result.demo_seed}, "
            f"{'SUCCESS' if result.success else 'failure'} after {result.steps} of {result.horizon} steps",
            media_type="text/markdown",
        ))
        used = [recording.demo_video[i] for i in recording.demo_indices]
        for k, frame in enumerate(used):
            self.stream.log(f"/demo/used/{k}", rr.EncodedImage(contents=jpeg_bytes(frame), media_type="image/jpeg"))
        self._send_jpegs("/demo/video", recording.demo_video)
        self._send_jpegs("/agent/camera", recording.frames)
        if recording.actions:
            actions = np.asarray(recording.actions, dtype=np.float64)
            for column, name in enumerate(ACTION_NAMES):
                self._send_scalars(f"/action/{name}", actions[:, column])
        success = np.zeros(len(recording.frames))
        success[-1:] = float(result.success)
        self._send_scalars("/success", success)
        if recording.attention and recording.feature_hw is not None:
            self._send_attention(np.stack(recording.attention), recording.feature_hw, len(used), recording.frames[0].shape[:2])
        self._set_time(steps - 1)
        self.stream.log("/events", rr.TextLog(f"episode {self.episodes}: {'success' if result.success else 'failure'}"))
        self._global_step += steps
        self.episodes += 1

    def _send_attention(self, weights: np.ndarray, feature_hw: tuple[int, int], n_demo: int, image_hw) -> None:
        """weights: (steps, layers, own tokens + demo tokens), averaged over heads and queries."""
        import rerun as rr

        height, width = feature_hw
        tokens = height * width
        n_layers = weights.shape[1]
        for layer in range(self._named_layers, n_layers):
            self.stream.log(f"/attention_on_demo/layer_{layer}", rr.SeriesLines(names=f"layer {layer}"), static=True)
        self._named_layers = max(self._named_layers, n_layers)
        share = weights[:, :, tokens:].sum(axis=2) / np.maximum(weights.sum(axis=2), 1e-12)
        for layer in range(n_layers):
            self._send_scalars(f"/attention_on_demo/layer_{layer}", share[:, layer].astype(np.float64))
        maps = weights[:, self.attention_layer].reshape(len(weights), 1 + n_demo, height, width)
        image_format = rr.components.ImageFormat(width=width, height=height, color_model="RGBA", channel_datatype="U8")
        scale = [image_hw[1] / width, image_hw[0] / height, 1.0]  # token grid -> frame pixels
        entities = ["/agent/camera/attention"] + [f"/demo/used/{k}/attention" for k in range(n_demo)]
        for index, entity in enumerate(entities):
            if self._overlay_layout.get(entity) != (feature_hw, tuple(image_hw)):  # once, not per episode
                self._overlay_layout[entity] = (feature_hw, tuple(image_hw))
                self.stream.log(entity, rr.Transform3D(scale=scale), static=True)
                self.stream.log(
                    entity,
                    rr.Image.from_fields(
                        format=image_format, draw_order=ATTENTION_DRAW_ORDER, opacity=ATTENTION_OPACITY,
                        magnification_filter="Linear",
                    ),
                    static=True,
                )
            overlays = np.stack([heat_overlay(grid) for grid in maps[:, index]])
            self.stream.send_columns(
                entity, indexes=self._times(len(overlays)), columns=rr.Image.columns(buffer=overlays.reshape(len(overlays), -1))
            )

    def close(self) -> None:
        self.stream.flush()


def heat_overlay(attention: np.ndarray) -> np.ndarray:
    """(h, w) attention -> (h, w, 4) uint8 RGBA at the token grid: red to yellow with hotness, transparent where
    cold. The viewer stretches it over the frame (see the module's docstring)."""
    grid = np.asarray(attention, dtype=np.float32)
    grid = grid - grid.min()
    grid = grid / grid.max() if grid.max() > 0 else grid
    rgba = np.empty((*grid.shape, 4), dtype=np.uint8)
    rgba[..., 0] = 255
    rgba[..., 1] = (255 * grid).astype(np.uint8)
    rgba[..., 2] = 0
    rgba[..., 3] = (255 * grid).astype(np.uint8)
    return rgba
