"""The agentview camera of a MOSAIC task: what it draws, into which buffers, and frames drawn after the fact.

:class:`AgentviewRendering` is the rendering half of every task environment (``MosaicTaskEnv`` in
:mod:`mosaic_data.tasks.base` inherits it before robosuite's environment): the model XML edits for the camera
(lighter visual meshes, :mod:`.render_meshes`; render buffers the size of the frame, :func:`size_render_buffers`),
the fast render flags, the GL context each scene draws and frees its objects in, and frames rendered later from a
kept :class:`FrameState`. None of it changes the physics.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Sequence
from typing import NamedTuple

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from mosaic_data.tasks.render_meshes import simplify_visual_meshes


class FrameState(NamedTuple):
    """What a frame of the agentview camera shows, kept to render it later (:meth:`AgentviewRendering.frame_state`).

    ``qpos``, ``mocap_pos`` and ``mocap_quat`` are the ones the simulation's kinematics were *last computed from*,
    not the current ones: robosuite's ``step`` ends with MuJoCo's integration, which moves ``qpos`` on but leaves
    the body and geom poses (what the renderer draws) those of the ``qpos`` before it. ``geom_rgba`` is the model's
    colours at that moment (press_button lights its lamps during an episode).
    """

    qpos: np.ndarray
    mocap_pos: np.ndarray
    mocap_quat: np.ndarray
    geom_rgba: np.ndarray


class AgentviewRendering:
    """Rendering of a robosuite environment's ``agentview`` camera; mixed in before the robosuite environment class.

    The environment sets ``image_height`` and ``image_width`` (the frame), ``fast_render`` (no shadows, reflections
    or skybox) and ``visual_face_budget`` (None: robosuite's own visual meshes) before robosuite builds the model.
    """

    image_height: int
    image_width: int
    fast_render: bool
    visual_face_budget: int | None

    def edit_model_xml(self, xml_str: str) -> str:
        """robosuite's path fixes, lighter copies of the detailed visual meshes (see ``render_meshes``), and render
        buffers sized to the frame (see :func:`size_render_buffers`)."""
        xml_str = super().edit_model_xml(xml_str)
        if self.visual_face_budget is not None:
            xml_str = simplify_visual_meshes(xml_str, self.visual_face_budget)
        return size_render_buffers(xml_str, self.image_height, self.image_width, shadows=not self.fast_render)

    # ------------------------------------------------------------------ frames rendered after the fact
    # A demonstration's frames are picked from its length, known only at its end, so the expert's single pass keeps
    # a FrameState per step and renders only the picked ones afterwards (mosaic_data.demos).
    _kinematics_source: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    """(qpos, mocap_pos, mocap_quat) the kinematics were last computed from: noted after every reset and at every
    physics substep, right after robosuite's ``forward``/``mj_step1`` (``_pre_action`` comes next)."""

    def reset(self):
        observations = super().reset()
        self._note_kinematics_source()
        return observations

    def _pre_action(self, action, policy_step=False):
        self._note_kinematics_source()
        super()._pre_action(action, policy_step)

    def _note_kinematics_source(self) -> None:
        data = self.sim.data
        self._kinematics_source = (data.qpos.copy(), data.mocap_pos.copy(), data.mocap_quat.copy())

    def frame_state(self) -> FrameState:
        """What :meth:`render_agentview` would draw now, to draw it later with :meth:`render_frame_states`.

        Saving the current ``qpos`` would not do: after a step the renderer draws the poses of the ``qpos`` before
        the step's last integration (see :class:`FrameState`), so the one noted then is kept.
        """
        if self._kinematics_source is None:
            raise RuntimeError("no frame state before the first reset")
        qpos, mocap_pos, mocap_quat = self._kinematics_source
        return FrameState(qpos, mocap_pos, mocap_quat, self.sim.model.geom_rgba.copy())

    def render_frame_states(self, states: Sequence[FrameState]) -> list[np.ndarray]:
        """The frames :meth:`render_agentview` drew (or would have drawn) when ``states`` were taken, bit for bit.

        Each state's kinematics are computed again (``mj_forward``, a function of ``qpos`` and the mocap poses) in a
        scratch ``MjData``, so the simulation is left as it is, and drawn by this scene's own render context (its
        scene, camera, options and GL buffers) the way robosuite's ``MjRenderContext.render``/``read_pixels`` do.
        Model-level poses (fixtures placed at reset) must be the instance's: render before the next reset.
        """
        context = self._offscreen_context
        if context is None:
            raise RuntimeError("this scene has no offscreen render context")
        model = self.sim.model._model
        scratch = mujoco.MjData(model)
        live_rgba = model.geom_rgba.copy()
        height, width = self.image_height, self.image_width
        viewport = mujoco.MjrRect(0, 0, width, height)
        frames = []
        self._make_gl_context_current()
        try:
            if width > context.con.offWidth or height > context.con.offHeight:  # as robosuite's render
                context.update_offscreen_size(max(width, model.vis.global_.offwidth), max(height, model.vis.global_.offheight))
            context.cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
            context.cam.fixedcamid = self.sim.model.camera_name2id("agentview")
            for state in states:
                scratch.qpos[:] = state.qpos
                scratch.mocap_pos[:] = state.mocap_pos
                scratch.mocap_quat[:] = state.mocap_quat
                model.geom_rgba[:] = state.geom_rgba
                mujoco.mj_forward(model, scratch)
                mujoco.mjv_updateScene(
                    model, scratch, context.vopt, context.pert, context.cam, mujoco.mjtCatBit.mjCAT_ALL, context.scn
                )
                mujoco.mjr_render(viewport, context.scn, context.con)
                image = np.empty((height, width, 3), dtype=np.uint8)
                mujoco.mjr_readPixels(image, None, viewport, context.con)
                frames.append(np.ascontiguousarray(image[::-1]))
        finally:
            model.geom_rgba[:] = live_rgba
        return frames

    def render_agentview(self) -> np.ndarray:
        """RGB image (H, W, 3) uint8 from the agentview camera, right side up.

        Makes this scene's GL context current first: robosuite's ``MjSim.render`` draws in whatever context is
        current, which is the last scene *built* in the process: with two scenes alive (an evaluation's agent and
        demonstrator, cached scenes of several variations) the older one would draw its frames with the other's GL
        objects, a wrong camera and wrong meshes (tested).
        """
        self._make_gl_context_current()
        image = self.sim.render(camera_name="agentview", height=self.image_height, width=self.image_width)
        return np.ascontiguousarray(image[::-1])

    @property
    def _offscreen_context(self):
        """robosuite's offscreen render context of this scene (None before the simulation exists or after it is freed)."""
        return self.sim._render_context_offscreen if self.sim is not None else None

    def _make_gl_context_current(self) -> None:
        if self._offscreen_context is not None:
            self._offscreen_context.gl_ctx.make_current()

    def _destroy_sim(self) -> None:
        """Free this scene's GL objects in its own GL context: robosuite frees them in whichever context is
        current, where closing one scene would delete the meshes and textures of another live one (tested)."""
        self._make_gl_context_current()
        super()._destroy_sim()

    def _configure_fast_render(self) -> None:
        """Turn off shadows, reflections and skybox: almost the same image at about twice the frame rate."""
        context = self._offscreen_context
        if context is None:
            return
        for flag in (mujoco.mjtRndFlag.mjRND_SHADOW, mujoco.mjtRndFlag.mjRND_REFLECTION, mujoco.mjtRndFlag.mjRND_SKYBOX):
            context.scn.flags[flag] = 0


def size_render_buffers(xml: str, height: int, width: int, shadows: bool) -> str:
    """The model XML with MuJoCo's offscreen buffer the size of the frame, and no shadow map when shadows are off.

    MuJoCo allocates its render buffers from the model's ``<visual>`` settings when the render context is made:
    by default a 640x480 offscreen framebuffer (4x multisampled) and a 4096x4096 shadow map, although
    ``fast_render`` draws no shadows and frames are 100x180. Sized down they take less memory per scene (the
    figure: ``pipelines/bench/render_bench.py``, the README's figures); the software renderer takes as long per
    frame either way. The viewport and the pixels drawn are the same, so the frames are the same (tested).
    """
    root = ET.fromstring(xml)
    visual = root.find("visual")
    if visual is None:
        visual = ET.SubElement(root, "visual")
    buffer = visual.find("global")
    if buffer is None:
        buffer = ET.SubElement(visual, "global")
    buffer.set("offwidth", str(int(width)))
    buffer.set("offheight", str(int(height)))
    if not shadows:
        quality = visual.find("quality")
        if quality is None:
            quality = ET.SubElement(visual, "quality")
        quality.set("shadowsize", "0")
    return ET.tostring(root, encoding="unicode")


def look_at_quat_wxyz(camera_pos: np.ndarray, target: np.ndarray) -> list[float]:
    """MuJoCo camera quaternion (w, x, y, z) looking from ``camera_pos`` at ``target`` with +z up.

    MuJoCo cameras look along their local -z with +y up.
    """
    forward = target - camera_pos
    forward = forward / np.linalg.norm(forward)
    right = np.cross(forward, np.array([0.0, 0.0, 1.0]))
    right = right / np.linalg.norm(right)
    up = np.cross(right, forward)
    matrix = np.stack([right, up, -forward], axis=1)
    return list(Rotation.from_matrix(matrix).as_quat(scalar_first=True))
