"""Lighter visual meshes: same physics, nearly the same frames, far fewer triangles, a shared on-disk cache."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
import robosuite

from mosaic_data.rollout import run_expert_episode
from mosaic_data.tasks import make_task_env
from mosaic_data.tasks.render_meshes import read_mesh, simplified_mesh_file

TETRAHEDRON = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64)
TETRAHEDRON_FACES = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]
PEDESTAL = Path(robosuite.__file__).parent / "models/assets/bases/meshes/rethink_mount/pedestal.stl"


def _binary_stl(path: Path) -> None:
    records = b"".join(
        struct.pack("<3f", 0, 0, 0) + b"".join(struct.pack("<3f", *TETRAHEDRON[i]) for i in face) + b"\0\0"
        for face in TETRAHEDRON_FACES
    )
    path.write_bytes(b"\0" * 80 + struct.pack("<I", len(TETRAHEDRON_FACES)) + records)


def _ascii_stl(path: Path) -> None:
    facets = "".join(
        "facet normal 0 0 0\n outer loop\n" + "".join(f"  vertex {x} {y} {z}\n" for x, y, z in TETRAHEDRON[list(face)]) + " endloop\nendfacet\n"
        for face in TETRAHEDRON_FACES
    )
    path.write_text(f"solid t\n{facets}endsolid t\n")


def test_read_mesh_welds_stl_corners_and_triangulates_obj_polygons(tmp_path):
    for writer, name in ((_binary_stl, "binary.stl"), (_ascii_stl, "ascii.stl")):
        writer(tmp_path / name)
        vertices, faces, normals = read_mesh(tmp_path / name)
        assert vertices.shape == (4, 3) and faces.shape == (4, 3) and normals is None, name
        assert np.allclose(np.sort(vertices, axis=0), np.sort(TETRAHEDRON, axis=0))
    # A quad with texture/normal indices and a triangle with negative (relative) indices; a repeated
    # corner at a normal seam is welded and takes the mean of its corners' normals.
    (tmp_path / "shape.obj").write_text(
        "o quad\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\nvn 0 -1 0\nf 1/1/1 2/1/1 3/1/1 4/1/1\n"
        "v 0 0 1\nv 1 0 0\nf -2//2 -1//2 1//2\n"
    )
    vertices, faces, normals = read_mesh(tmp_path / "shape.obj")
    assert vertices.shape == (5, 3)
    assert faces.shape == (3, 3)
    origin = np.flatnonzero((vertices == 0).all(axis=1))[0]
    assert np.allclose(normals[origin], np.array([0, -1, 2]) / np.sqrt(5))  # two quad corners, one triangle corner
    (tmp_path / "shape.ply").write_text("ply")
    with pytest.raises(ValueError, match="only .stl and .obj"):
        read_mesh(tmp_path / "shape.ply")


def test_simplified_mesh_is_made_once_and_small_meshes_are_left_alone(tmp_path, monkeypatch):
    monkeypatch.setenv("MOSAIC_CACHE_DIR", str(tmp_path / "cache"))
    original_faces = len(read_mesh(PEDESTAL)[1])  # an STL: no normals of its own, MuJoCo computes them
    first = simplified_mesh_file(PEDESTAL, 800)
    assert first is not None and first.parent == tmp_path / "cache" / "meshes"
    vertices, faces, _ = read_mesh(first)
    assert len(faces) < original_faces
    assert len(faces) / 800 in {2.0**k for k in range(8)}  # the budget, doubled until within the tolerance
    assert faces.min() >= 0 and faces.max() < len(vertices)
    made = first.stat().st_mtime_ns
    assert simplified_mesh_file(PEDESTAL, 800) == first and first.stat().st_mtime_ns == made
    _binary_stl(tmp_path / "small.stl")
    assert simplified_mesh_file(tmp_path / "small.stl", 800) is None
    assert not [path for path in (tmp_path / "cache" / "meshes").iterdir() if path.name.startswith(".")]  # no temporaries left


def _visual_faces(env) -> int:
    model = env.sim.model._model
    return sum(int(model.mesh_facenum[model.geom_dataid[g]]) for g in range(model.ngeom) if model.geom_type[g] == 7 and model.geom_group[g] == 1)


@pytest.mark.parametrize("robot", ["panda", "sawyer"])
def test_lighter_meshes_keep_the_physics_and_the_picture(robot):
    simplified = make_task_env("door", 0, robot, image_height=48, image_width=88)
    original = make_task_env("door", 0, robot, image_height=48, image_width=88, visual_face_budget=None)
    try:
        assert _visual_faces(simplified) < _visual_faces(original) / 2.5
        episodes = [run_expert_episode(env, 5, record_frames=True, record_final_frame=False) for env in (simplified, original)]
        assert np.array_equal(np.asarray(episodes[0].states), np.asarray(episodes[1].states))
        assert np.array_equal(np.asarray(episodes[0].actions), np.asarray(episodes[1].actions))
        difference = np.abs(np.asarray(episodes[0].frames, dtype=np.int16) - np.asarray(episodes[1].frames, dtype=np.int16))
        assert difference.mean() < 3.0, difference.mean()  # only the robot's silhouette edges and shading move
        assert (difference.max(axis=-1) > 40).mean() < 0.03
    finally:
        simplified.close()
        original.close()


def test_a_mesh_no_simplification_keeps_within_tolerance_is_left_as_it_is(tmp_path, monkeypatch):
    """1000 separate small triangles scattered over a metre: dropping any of them moves the surface by far more
    than the tolerance, so the original file is used (not a copy with averaged normals and as many faces)."""
    monkeypatch.setenv("MOSAIC_CACHE_DIR", str(tmp_path / "cache"))
    rng = np.random.default_rng(0)
    corners = rng.uniform(0, 1, (1000, 1, 3)) + rng.uniform(0, 0.01, (1000, 3, 3))
    records = b"".join(struct.pack("<3f", 0, 0, 0) + corners[i].astype("<f4").tobytes() + b"\0\0" for i in range(len(corners)))
    soup = tmp_path / "soup.stl"
    soup.write_bytes(b"\0" * 80 + struct.pack("<I", len(corners)) + records)
    assert simplified_mesh_file(soup, 800) is None
    assert [path.suffix for path in (tmp_path / "cache" / "meshes").iterdir()] == [".keep"]  # decided once, remembered
    assert simplified_mesh_file(soup, 800) is None
