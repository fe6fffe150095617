"""Pick and place: four grocery items in a row, four bins in a row; put one item into one bin.

Variation ``i``: item ``i // 4`` (robosuite's milk carton, bread loaf, cereal box and soda can) and bin
``i % 4``. The bins stand side by side on the far half of the table and look alike; they are told apart by
their position, from the robot's view (left = +y):

====  ===========  ==========  ======================================
 i    item         bin         description
====  ===========  ==========  ======================================
 0    milk         far left    put the milk carton in the far-left bin
 1    milk         mid left    put the milk carton in the middle-left bin
 2    milk         mid right   put the milk carton in the middle-right bin
 3    milk         far right   put the milk carton in the far-right bin
 4    bread        far left    put the bread loaf in the far-left bin
 ...  ...          ...         (same pattern)
 15   can          far right   put the soda can in the far-right bin
====  ===========  ==========  ======================================

The items are robosuite's :class:`~robosuite.models.objects.MilkObject`, ``BreadObject``,
``CerealObject`` and ``CanObject`` (free joints); the bins are robosuite's open-top
:class:`~robosuite.models.objects.Bin` without a joint (fixtures). Every instance shuffles the four items
over four slots in a row between the robot and the bins (``SLOT_Y_M``), with a small random offset and turn
each, and slides the row of bins a little along y; all four items are always there, so only the variation (its
description) tells which item goes into which bin.

Success: the asked item's centre lies over the asked bin's floor (inside its walls in x and y), the item
touches that bin, and the gripper is not touching the item (it has been let go). Any other item in that bin,
or the asked item in another bin, does not count.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from robosuite.models.objects import Bin, BreadObject, CanObject, CerealObject, MilkObject
from scipy.spatial.transform import Rotation

from mosaic_data.tasks.base import MosaicTaskEnv, Variation
from mosaic_data.tasks.spec import BIN_NAMES, ITEM_NAMES, TASK_SPECS

ITEM_CLASSES = {"milk": MilkObject, "bread": BreadObject, "cereal": CerealObject, "can": CanObject}
ITEM_YAW_RAD = {name: np.pi / 2 for name in ITEM_NAMES}
"""Each item's nominal turn about z: its narrow side (its own y axis) along the world's x axis, so the hands,
which are long along their closing direction, reach in between the items; the cereal box then shows its
printed face to the camera."""
BIN_Y_M = (0.24, 0.08, -0.08, -0.24)
"""Bin centres along y (+y is the robot's left)."""
BIN_OUTER_SIZE_M = (0.14, 0.14, 0.05)
BIN_WALL_M = 0.01
BIN_INNER_HALF_M = BIN_OUTER_SIZE_M[0] / 2 - BIN_WALL_M
SLOT_Y_M = (0.18, 0.06, -0.06, -0.18)
"""Start slots of the items along y."""


class FixedBin(Bin):
    """robosuite's bin without its free joint: a fixture the instance places with ``set_fixture_pose``."""

    def _get_geom_attrs(self) -> dict:
        attrs = super()._get_geom_attrs()
        attrs["joints"] = None
        return attrs


class PickPlace(MosaicTaskEnv):
    task_name: ClassVar[str] = "pick_place"
    variations: ClassVar[tuple[Variation, ...]] = TASK_SPECS["pick_place"].variations
    horizon_steps: ClassVar[int] = TASK_SPECS["pick_place"].horizon_steps
    slot_x_m: ClassVar[float] = -0.12
    bin_x_m: ClassVar[float] = 0.035
    item_jitter_m: ClassVar[float] = 0.01
    item_yaw_jitter_rad: ClassVar[float] = 0.2
    bin_jitter_m: ClassVar[float] = 0.015

    def _load_task_objects(self) -> list:
        self.items = {name: ITEM_CLASSES[name](name=name) for name in ITEM_NAMES}
        self.bins = {
            name: FixedBin(
                name=f"{name}_bin", bin_size=BIN_OUTER_SIZE_M, wall_thickness=BIN_WALL_M, transparent_walls=False
            )
            for name in BIN_NAMES
        }
        return [*self.items.values(), *self.bins.values()]

    def _setup_task_references(self) -> None:
        self.item_body_ids = {name: self.body_id(item.root_body) for name, item in self.items.items()}
        self.bin_body_ids = {name: self.body_id(b.root_body) for name, b in self.bins.items()}
        self.item_extents = {name: self._body_frame_extent(item) for name, item in self.items.items()}

    def _body_frame_extent(self, item) -> tuple[np.ndarray, np.ndarray]:
        """Lowest and highest corner (3,) of the item's collision meshes in its root body's frame (turned by
        its nominal yaw, i.e. as it stands at the start)."""
        model = self.sim.model._model
        points = []
        for geom_name in item.contact_geoms:
            geom_id = self.sim.model.geom_name2id(geom_name)
            mesh_id = model.geom_dataid[geom_id]
            start, count = model.mesh_vertadr[mesh_id], model.mesh_vertnum[mesh_id]
            vertices = model.mesh_vert[start : start + count]
            geom_rot = Rotation.from_quat(model.geom_quat[geom_id], scalar_first=True)
            # The mesh body ("object") sits at the root body's origin in robosuite's item models.
            points.append(geom_rot.apply(vertices) + model.geom_pos[geom_id])
        points = Rotation.from_euler("z", ITEM_YAW_RAD[item.name]).apply(np.concatenate(points))
        return points.min(axis=0), points.max(axis=0)

    def _place_instance(self, rng: np.random.Generator) -> None:
        # The row of bins slides along y only: one step closer to the camera and its front edge leaves the image.
        bin_shift = rng.uniform(-self.bin_jitter_m, self.bin_jitter_m)
        for name, y in zip(BIN_NAMES, BIN_Y_M):
            centre_z = self.table_offset[2] + BIN_OUTER_SIZE_M[2] / 2
            self.set_fixture_pose(self.bin_body_ids[name], (self.bin_x_m, y + bin_shift, centre_z))
        slots = rng.permutation(len(SLOT_Y_M))
        for name, slot in zip(ITEM_NAMES, slots):
            jitter = rng.uniform(-self.item_jitter_m, self.item_jitter_m, size=2)
            yaw = ITEM_YAW_RAD[name] + rng.uniform(-self.item_yaw_jitter_rad, self.item_yaw_jitter_rad)
            low, _ = self.item_extents[name]
            pos = (self.slot_x_m + jitter[0], SLOT_Y_M[slot] + jitter[1], self.table_offset[2] - low[2] + 0.001)
            quat = Rotation.from_euler("z", yaw).as_quat(scalar_first=True)
            self.sim.data.set_joint_qpos(self.items[name].joints[0], np.concatenate([pos, quat]))

    # ------------------------------------------------------------------ geometry the success test and expert read
    def item_position(self, name: str) -> np.ndarray:
        return np.array(self.sim.data.xpos[self.item_body_ids[name]])

    def item_yaw(self, name: str) -> float:
        matrix = self.sim.data.xmat[self.item_body_ids[name]].reshape(3, 3)
        return float(np.arctan2(matrix[1, 0], matrix[0, 0]))

    def bin_position(self, name: str) -> np.ndarray:
        """Centre of the bin's floor top."""
        centre = np.array(self.sim.data.xpos[self.bin_body_ids[name]])
        return centre + np.array([0.0, 0.0, -BIN_OUTER_SIZE_M[2] / 2 + BIN_WALL_M])

    def item_in_bin(self, item: str, bin_name: str) -> bool:
        offset = self.item_position(item) - self.bin_position(bin_name)
        inside = bool(np.all(np.abs(offset[:2]) < BIN_INNER_HALF_M))
        return inside and self.check_contact(self.items[item], self.bins[bin_name])

    def is_released(self, item: str) -> bool:
        return not self.check_contact(self.robot.gripper["right"], self.items[item])

    # ------------------------------------------------------------------ success
    def _goal_reached(self, variation: Variation) -> bool:
        item = variation.params["item"]
        return self.item_in_bin(item, variation.params["bin"]) and self.is_released(item)
