"""Lighter visual meshes for the camera: the robots' visual meshes simplified to a face budget, cached on disk.

Why: the renderer on a machine without a GPU (Mesa's llvmpipe) transforms every triangle of every mesh in
view on the CPU. robosuite's visual meshes are detailed far beyond what a 100x180 camera resolves (the Panda
alone has ~170k triangles, its pedestal 33k), so they cost ~85% of a control step with a rendered frame. The
meshes with more faces than the budget are simplified (quadric edge collapse, ``fast_simplification``) as far
as the surface stays within a tolerance of the original, keeping the file's own normals, and the model is
pointed at the simplified copies.

Only meshes used by purely visual geoms (``contype = conaffinity = 0``, in visual group 1) are touched, and
only their files change: collision geometry, masses and inertias (robosuite's bodies give theirs explicitly)
stay as they are, so the physics is bit for bit the same (tested). The simplified files live in
``$MOSAIC_CACHE_DIR`` (default ``~/.cache/mosaic``)/``meshes``, named by a hash of the source file and the
settings; they are written atomically, so parallel workers can share the cache.
"""

from __future__ import annotations

import hashlib
import os
import struct
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from mosaic_data.atomic_files import write_bytes_atomically

VISUAL_FACE_BUDGET = 800
"""Faces a visual mesh is first simplified to; doubled until the surface is within ``TOLERANCE_M``. Frames differ
from those of robosuite's meshes only along silhouette edges (the speed-up is in the README, "Rendering on a
CPU")."""
TOLERANCE_M = 0.005
"""Largest distance (99th percentile) from an original vertex to the simplified surface: under a pixel of the
100x180 camera at the robot (~1 cm), and enough to keep the Sawyer's layered shells from showing through."""
_ALGORITHM_VERSION = "6"  # part of the cache key: bump when the simplification changes
_VISUAL_GROUP = "1"


def cache_dir() -> Path:
    return Path(os.environ.get("MOSAIC_CACHE_DIR", Path.home() / ".cache" / "mosaic")).expanduser() / "meshes"


def simplify_visual_meshes(xml: str, face_budget: int = VISUAL_FACE_BUDGET) -> str:
    """The model XML with every purely visual mesh over ``face_budget`` faces pointed at a simplified copy."""
    root = ET.fromstring(xml)
    visual_only = _meshes_used_only_by_visual_geoms(root)
    changed = False
    for mesh in root.iter("mesh"):
        source = mesh.get("file")
        if mesh.get("name") not in visual_only or source is None or not os.path.isabs(source):
            continue
        simplified = simplified_mesh_file(Path(source), face_budget)
        if simplified is not None:
            mesh.set("file", str(simplified))
            changed = True
    return ET.tostring(root, encoding="unicode") if changed else xml


def _meshes_used_only_by_visual_geoms(root: ET.Element) -> set[str]:
    visual, other = set(), set()
    for geom in root.iter("geom"):
        name = geom.get("mesh")
        if name is None:
            continue
        purely_visual = geom.get("contype") == "0" and geom.get("conaffinity") == "0" and geom.get("group") == _VISUAL_GROUP
        (visual if purely_visual else other).add(name)
    return visual - other


def simplified_mesh_file(source: Path, face_budget: int) -> Path | None:
    """Path of ``source`` simplified from ``face_budget`` faces on (made once, then cached); None when the
    original is kept: already within the budget, or no simplification stays within the tolerance."""
    content = source.read_bytes()
    key = hashlib.sha1(content + f"|{face_budget}|{TOLERANCE_M}|{_ALGORITHM_VERSION}".encode()).hexdigest()[:20]
    target = cache_dir() / f"{source.stem}-{key}.obj"
    keep_mark = target.with_suffix(".keep")
    if target.is_file():
        return target
    if keep_mark.is_file():
        return None
    vertices, faces, normals = read_mesh(source, content)
    target.parent.mkdir(parents=True, exist_ok=True)
    reduced = simplify_within_tolerance(vertices, faces, face_budget) if len(faces) > face_budget else None
    if reduced is None:
        write_bytes_atomically(keep_mark, b"")
        return None
    simplified, faces = reduced
    if normals is not None:  # the file's own normals, from the nearest original vertex: the same shading
        from scipy.spatial import cKDTree

        normals = normals[cKDTree(vertices).query(simplified)[1]]
    write_bytes_atomically(target, _obj_bytes(simplified, faces, normals))
    return target


def simplify_within_tolerance(
    vertices: np.ndarray, faces: np.ndarray, face_budget: int, tolerance_m: float = TOLERANCE_M
) -> tuple[np.ndarray, np.ndarray] | None:
    """The fewest faces (``face_budget``, doubled as needed) whose surface stays within ``tolerance_m`` of every
    original vertex, or None when only the original does. A fixed face count is not enough: robosuite's Sawyer
    layers white and grey shells a millimetre apart, and a coarse outer shell lets the inner one show through."""
    import fast_simplification

    probe = vertices[np.random.default_rng(0).choice(len(vertices), size=min(len(vertices), 4000), replace=False)]
    count = face_budget
    while count < len(faces):
        simplified, simplified_faces = fast_simplification.simplify(vertices, faces, target_count=count)
        if _surface_distance(probe, simplified, simplified_faces) <= tolerance_m:
            return simplified, simplified_faces
        count *= 2
    return None


def _surface_distance(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, candidates: int = 16) -> float:
    """99th percentile of the distance from ``points`` to the triangles ``faces`` (exact point-triangle
    distances to the ``candidates`` triangles with the nearest centroids)."""
    from scipy.spatial import cKDTree

    corners = vertices[faces]
    _, nearest = cKDTree(corners.mean(axis=1)).query(points, k=min(candidates, len(faces)))
    nearest = nearest.reshape(len(points), -1)
    repeated = np.repeat(points, nearest.shape[1], axis=0)
    a, b, c = (corners[nearest.reshape(-1), i] for i in range(3))
    distances = _point_triangle_distance(repeated, a, b, c).reshape(nearest.shape).min(axis=1)
    return float(np.percentile(distances, 99))


def _point_triangle_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Row-wise distance from points ``p`` to triangles ``abc`` (all (N, 3)): to the plane when the point
    projects inside the triangle, else to the nearest edge."""
    ab, ac, ap = b - a, c - a, p - a
    normal = np.cross(ab, ac)
    area2 = np.einsum("ij,ij->i", normal, normal)
    safe = np.maximum(area2, 1e-30)
    height = np.einsum("ij,ij->i", ap, normal) / safe
    projected = ap - height[:, None] * normal
    d00, d01, d11 = (np.einsum("ij,ij->i", x, y) for x, y in ((ab, ab), (ab, ac), (ac, ac)))
    d20, d21 = np.einsum("ij,ij->i", projected, ab), np.einsum("ij,ij->i", projected, ac)
    denominator = np.maximum(d00 * d11 - d01 * d01, 1e-30)
    v = (d11 * d20 - d01 * d21) / denominator
    w = (d00 * d21 - d01 * d20) / denominator
    inside = (v >= 0) & (w >= 0) & (v + w <= 1) & (area2 > 1e-30)
    to_plane = np.abs(height) * np.sqrt(area2)
    to_edges = np.minimum.reduce([_point_segment_distance(p, a, b), _point_segment_distance(p, b, c), _point_segment_distance(p, c, a)])
    return np.where(inside, to_plane, to_edges)


def _point_segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-30), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1)


def read_mesh(path: Path, content: bytes | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Vertices (V, 3) float64, triangles (F, 3) int64 and unit vertex normals (V, 3) or None (when the file
    gives none: MuJoCo computes them) of an STL (binary or ASCII) or OBJ file, welded."""
    content = path.read_bytes() if content is None else content
    suffix = path.suffix.lower()
    corner_normals = None
    if suffix == ".stl":
        corners = _stl_corners(content).reshape(-1, 3)
        triangles = np.arange(len(corners)).reshape(-1, 3)
    elif suffix == ".obj":
        corners, triangles, corner_normals = _obj_mesh(content.decode("utf-8", errors="replace"))
    else:
        raise ValueError(f"cannot simplify {path}: only .stl and .obj meshes are supported")
    # Weld corners at the same place (STL repeats them per triangle, OBJ at normal/texture seams): an unwelded
    # surface is a patchwork of open borders, which the simplification tears into holes.
    vertices, inverse = np.unique(corners, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    triangles = inverse[triangles]
    keep = (triangles[:, 0] != triangles[:, 1]) & (triangles[:, 1] != triangles[:, 2]) & (triangles[:, 0] != triangles[:, 2])
    normals = None
    if corner_normals is not None:  # the welded vertex takes the mean of its corners' normals
        normals = np.zeros_like(vertices)
        np.add.at(normals, inverse, corner_normals)
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    return vertices.astype(np.float64), triangles[keep].astype(np.int64), normals


def _stl_corners(content: bytes) -> np.ndarray:
    if len(content) >= 84:
        (count,) = struct.unpack_from("<I", content, 80)
        if 84 + 50 * count == len(content):
            records = np.frombuffer(content, dtype=np.dtype([("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attr", "<u2")]), count=count, offset=84)
            return records["corners"].astype(np.float64)
    numbers = [line.split()[1:4] for line in content.decode("ascii", errors="replace").splitlines() if line.strip().startswith("vertex")]
    return np.asarray(numbers, dtype=np.float64).reshape(-1, 3, 3)


def _obj_mesh(text: str) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Corners (positions, one per face corner so that each keeps its own normal), triangles, corner normals."""
    vertices, normals, corner_positions, corner_normals = [], [], [], []
    for line in text.splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "v":
            vertices.append([float(value) for value in parts[1:4]])
        elif parts[0] == "vn":
            normals.append([float(value) for value in parts[1:4]])
        elif parts[0] == "f":
            fields = [part.split("/") for part in parts[1:]]
            polygon = [_obj_index(int(field[0]), len(vertices)) for field in fields]
            polygon_normals = [_obj_index(int(field[2]), len(normals)) if len(field) > 2 and field[2] else None for field in fields]
            for i in range(1, len(polygon) - 1):
                for corner in (0, i, i + 1):
                    corner_positions.append(vertices[polygon[corner]])
                    normal = polygon_normals[corner]
                    corner_normals.append(normals[normal] if normal is not None else (0.0, 0.0, 0.0))
    corners = np.asarray(corner_positions, dtype=np.float64).reshape(-1, 3)
    triangles = np.arange(len(corners), dtype=np.int64).reshape(-1, 3)
    corner_normals_array = np.asarray(corner_normals, dtype=np.float64).reshape(-1, 3)
    has_normals = len(corner_normals_array) and np.linalg.norm(corner_normals_array, axis=1).min() > 0
    return corners, triangles, corner_normals_array if has_normals else None


def _obj_index(index: int, count: int) -> int:
    """OBJ indices count from 1, or back from the last element when negative."""
    return index - 1 if index > 0 else count + index


def _obj_bytes(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray | None) -> bytes:
    lines = [f"v {x:.7g} {y:.7g} {z:.7g}" for x, y, z in vertices]
    if normals is None:
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    else:
        lines += [f"vn {x:.5f} {y:.5f} {z:.5f}" for x, y, z in normals]
        lines += [f"f {a + 1}//{a + 1} {b + 1}//{b + 1} {c + 1}//{c + 1}" for a, b, c in faces]
    return ("\n".join(lines) + "\n").encode()
