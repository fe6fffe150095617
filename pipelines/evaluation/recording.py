"""One rerun recording per evaluation: demonstration, agent camera with the policy's attention, actions, success.

Timelines: ``eval_step`` runs through all recorded episodes one after the other, ``episode`` jumps between them
and ``step`` is the step within an episode. Per step the recording holds:

* ``/demo/video``: the demonstrator's video, played alongside the rollout (frame ``step`` of it);
* ``/demo/used/<k>``: the demonstration frames the policy conditions on, each with ``attention`` drawn over it:
  where the current observation's queries look in that frame;
* ``/agent/camera`` with ``/agent/camera/attention``: the agent's camera and the attention on its own tokens;
* ``/action/<dim>``, ``/attention_on_demo/layer_<i>`` (share of attention on demo tokens) and ``/success``.

Attention is the chosen layer's weights averaged over heads and query locations, normalised per image (the
hottest token of each frame is fully drawn), and upsampled to the frame.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from mosaic_data.collection.schema import ACTION_NAMES

from .rollouts import EpisodeResult



def blueprint(n_demo_frames: int):
    import rerun.blueprint as rrb

    used = [rrb.Spatial2DView(origin=f"/demo/used/{k}", name=f"demo frame {k}") for k in range(n_demo_frames)]
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial2DView(origin="/demo/video", name="demonstration (demonstrator)"),
                rrb.Grid(*used) if used else rrb.TextDocumentView(origin="/episode"),
                rrb.TextDocumentView(origin="/episode", name="episode"),
            ),
            rrb.Vertical(
                rrb.Spatial2DView(origin="/agent", name="agent camera + attention on its own tokens"),
                rrb.TimeSeriesView(origin="/action", name="action (target pose, gripper)"),
                rrb.TimeSeriesView(origin="/attention_on_demo", name="attention on the demonstration"),
                rrb.TimeSeriesView(origin="/success", name="success"),
            ),
        ),
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

    def log_episode(self, result: EpisodeResult) -> None:
        import rerun as rr

        recording = result.recording
        if recording is None:
            return
        log = self.stream.log
        self.stream.set_time("episode", sequence=self.episodes)
        self.stream.set_time("eval_step", sequence=self._global_step)
        self.stream.set_time("step", sequence=0)
        log("/episode", rr.TextDocument(
            f"**{result.agent}** on {result.task} variation {result.variation}: {result.description}\n\n"
            f"agent instance seed {result.seed}, demonstration seed {result.demo_seed}, "
            f"{'SUCCESS' if result.success else 'failure'} after {result.steps} of {result.horizon} steps",
            media_type="text/markdown",
        ))
        used = [recording.demo_video[i] for i in recording.demo_indices]
        for step in range(max(len(recording.frames), len(recording.demo_video), 1)):
            self.stream.set_time("eval_step", sequence=self._global_step)
            self.stream.set_time("step", sequence=step)
            if step < len(recording.demo_video):
                log("/demo/video", rr.Image(recording.demo_video[step]))
            if step < len(recording.frames):
                log("/agent/camera", rr.Image(recording.frames[step]))
                for name, value in zip(ACTION_NAMES, recording.actions[step]):
                    log(f"/action/{name}", rr.Scalars(float(value)))
            if step == 0:
                for k, frame in enumerate(used):
                    log(f"/demo/used/{k}", rr.Image(frame))
            if step < len(recording.attention) and recording.feature_hw is not None:
                self._log_attention(recording.attention[step], recording.feature_hw, len(used), recording.frames[step].shape[:2])
            if step < len(recording.frames):
                last = step == len(recording.frames) - 1
                log("/success", rr.Scalars(float(result.success and last)))
            self._global_step += 1
        log("/events", rr.TextLog(f"episode {self.episodes}: {'success' if result.success else 'failure'}"))
        self.episodes += 1

    def _log_attention(self, weights: np.ndarray, feature_hw: tuple[int, int], n_demo: int, image_hw) -> None:
        """weights: (layers, own tokens + demo tokens), averaged over heads and queries."""
        import rerun as rr

        tokens = feature_hw[0] * feature_hw[1]
        for layer, row in enumerate(weights):
            self.stream.log(f"/attention_on_demo/layer_{layer}", rr.Scalars(float(row[tokens:].sum() / max(row.sum(), 1e-12))))
        row = weights[self.attention_layer]
        maps = row.reshape(1 + n_demo, *feature_hw)
        self.stream.log("/agent/camera/attention", rr.Image(heat_overlay(maps[0], image_hw), draw_order=10.0))
        for k in range(n_demo):
            self.stream.log(f"/demo/used/{k}/attention", rr.Image(heat_overlay(maps[1 + k], image_hw), draw_order=10.0))

    def close(self) -> None:
        self.stream.flush()


def heat_overlay(attention: np.ndarray, image_hw: tuple[int, int]) -> np.ndarray:
    """(h, w) attention -> (H, W, 4) uint8 RGBA: red to yellow with hotness, transparent where cold."""
    grid = torch.as_tensor(attention, dtype=torch.float32)[None, None]
    grid = F.interpolate(grid, size=tuple(image_hw), mode="bilinear", align_corners=False)[0, 0].numpy()
    grid = grid - grid.min()
    grid = grid / grid.max() if grid.max() > 0 else grid
    rgba = np.empty((*grid.shape, 4), dtype=np.uint8)
    rgba[..., 0] = 255
    rgba[..., 1] = (255 * grid).astype(np.uint8)
    rgba[..., 2] = 0
    rgba[..., 3] = (170 * grid).astype(np.uint8)
    return rgba
