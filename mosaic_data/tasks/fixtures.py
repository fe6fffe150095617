"""Fixtures (doors, cabinets, button machines) built from the Meta-World meshes of the installed package.

Meta-World ships its meshes under ``metaworld/assets/objects/meshes``; its MJCF files use default classes and
``<include>`` chains that robosuite's loaders do not follow, and they face the Sawyer along +y. We therefore
write a small robosuite-format MJCF per fixture (meshes by absolute path, visual geoms in group 1, collision
geoms in group 0) and load it as a jointless :class:`robosuite.models.objects.MujocoXMLObject`.

Coordinates given to :class:`FixtureBuilder` are in the fixture's own frame, which uses robosuite's
convention: -x faces the robot, +y is the robot's left, +z up.
"""

from __future__ import annotations

import hashlib
import tempfile
from pathlib import Path
from xml.sax.saxutils import quoteattr

import metaworld
from robosuite.models.objects import MujocoXMLObject

from mosaic_data.atomic_files import write_bytes_atomically

METAWORLD_OBJECTS_DIR = Path(metaworld.__file__).parent / "assets" / "objects"
METAWORLD_MESHES_DIR = METAWORLD_OBJECTS_DIR / "meshes"
METAWORLD_TEXTURES_DIR = METAWORLD_OBJECTS_DIR.parent / "textures"

_CACHE_DIR = Path(tempfile.gettempdir()) / "mosaic_fixture_xml"


def _fmt(values) -> str:
    return " ".join(f"{float(v):.6g}" for v in values)


class FixtureBuilder:
    """Accumulates meshes, materials and a body tree, then renders robosuite-format MJCF."""

    def __init__(self, name: str) -> None:
        self.name = name
        self._assets: list[str] = []
        self._asset_names: set[str] = set()
        self._body: list[str] = []

    # assets ---------------------------------------------------------------
    def mesh(self, name: str, relative_path: str, scale: float = 1.0) -> str:
        """Declare a Meta-World mesh (path relative to ``meshes/``); returns the asset name."""
        if name not in self._asset_names:
            path = METAWORLD_MESHES_DIR / relative_path
            if not path.is_file():
                raise FileNotFoundError(f"Meta-World mesh {path} is missing: reinstall metaworld==3.0.0")
            self._assets.append(f'<mesh name="{name}" file="{path}" scale="{_fmt([scale] * 3)}"/>')
            self._asset_names.add(name)
        return name

    def material(self, name: str, rgba, texture: str | None = None, shininess: float = 0.3) -> str:
        """Declare a material; ``texture`` names a Meta-World texture file (``textures/``)."""
        if name not in self._asset_names:
            texture_attr = ""
            if texture is not None:
                self._assets.append(
                    f'<texture name="{name}_tex" type="cube" file="{METAWORLD_TEXTURES_DIR / texture}"/>'
                )
                texture_attr = f' texture="{name}_tex" texuniform="true"'
            self._assets.append(
                f'<material name="{name}" rgba="{_fmt(rgba)}" shininess="{shininess}" specular="0.3"{texture_attr}/>'
            )
            self._asset_names.add(name)
        return name

    # body tree ------------------------------------------------------------
    def open_body(self, name: str, pos=(0, 0, 0), quat=None, euler=None) -> None:
        orientation = ""
        if quat is not None:
            orientation = f' quat="{_fmt(quat)}"'
        elif euler is not None:
            orientation = f' euler="{_fmt(euler)}"'
        self._body.append(f'<body name={quoteattr(name)} pos="{_fmt(pos)}"{orientation}>')

    def close_body(self) -> None:
        self._body.append("</body>")

    def visual_mesh(self, mesh: str, material: str, pos=(0, 0, 0), euler=(0, 0, 0)) -> None:
        self._body.append(
            f'<geom type="mesh" mesh="{mesh}" material="{material}" pos="{_fmt(pos)}" euler="{_fmt(euler)}" '
            'group="1" contype="0" conaffinity="0" mass="0"/>'
        )

    def visual_box(self, size, material: str, pos=(0, 0, 0), euler=(0, 0, 0)) -> None:
        self._body.append(
            f'<geom type="box" size="{_fmt(size)}" material="{material}" pos="{_fmt(pos)}" euler="{_fmt(euler)}" '
            'group="1" contype="0" conaffinity="0" mass="0"/>'
        )

    def collision(self, geom_type: str, size, pos=(0, 0, 0), euler=(0, 0, 0), mass: float = 0.05, name=None) -> None:
        name_attr = f" name={quoteattr(name)}" if name else ""
        self._body.append(
            f'<geom{name_attr} type="{geom_type}" size="{_fmt(size)}" pos="{_fmt(pos)}" euler="{_fmt(euler)}" '
            f'group="0" rgba="0.5 0.5 0.5 1" mass="{mass}" friction="1 0.005 0.0001" solref="0.01 1" '
            'solimp="0.99 0.99 0.01"/>'
        )

    def solid_box(self, size, material: str, pos=(0, 0, 0), euler=(0, 0, 0), mass: float = 0.05) -> None:
        """A box that is both seen and collided with."""
        self.visual_box(size, material, pos, euler)
        self.collision("box", size, pos, euler, mass)

    def joint(self, name: str, joint_type: str, axis, range_, damping: float = 2.0, **extra) -> None:
        extra_attrs = "".join(f' {key}="{value}"' for key, value in extra.items())
        self._body.append(
            f'<joint name="{name}" type="{joint_type}" axis="{_fmt(axis)}" range="{_fmt(range_)}" limited="true" '
            f'damping="{damping}" armature="0.001"{extra_attrs}/>'
        )

    def site(self, name: str, pos=(0, 0, 0), size: float = 0.005, rgba=(1, 0, 0, 0)) -> None:
        self._body.append(f'<site name="{name}" pos="{_fmt(pos)}" size="{size}" rgba="{_fmt(rgba)}"/>')

    def raw(self, xml: str) -> None:
        self._body.append(xml)

    # output ---------------------------------------------------------------
    def to_xml(self) -> str:
        return (
            f'<mujoco model="{self.name}">\n<asset>\n'
            + "\n".join(self._assets)
            + '\n</asset>\n<worldbody>\n<body>\n<body name="object">\n'
            + "\n".join(self._body)
            + "\n</body>\n</body>\n</worldbody>\n</mujoco>\n"
        )

    def build(self, joints: list[dict] | None = None) -> MujocoXMLObject:
        """Write the MJCF to a content-addressed cache file and load it as an object.

        ``joints`` as robosuite takes them (e.g. ``[{"type": "free"}]`` for a loose object); none by default,
        which makes a fixed fixture.
        """
        xml = self.to_xml()
        _CACHE_DIR.mkdir(parents=True, exist_ok=True)
        path = _CACHE_DIR / f"{self.name}_{hashlib.sha1(xml.encode()).hexdigest()[:12]}.xml"
        if not path.exists():
            write_bytes_atomically(path, xml.encode())
        return MujocoXMLObject(str(path), name=self.name, joints=joints, duplicate_collision_geoms=False)
