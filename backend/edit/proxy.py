"""Edit proxies: one file format for the fitted plane, the fitted cylinder and any mesh with UVs.

The backend writes a proxy after ``fit-plane`` / ``fit-cylinder``; the Blender add-on turns it
into an ordinary mesh object with an image-texture material, lets the artist move it with the
gizmos and paint it with Texture Paint, and writes it back (or writes any UV-mapped mesh the
artist picked) for the bake.

File format: ``proxy.json`` (UTF-8 JSON, schema 1)
----------------------------------------------------

.. code-block:: text

    {
      "schema": 1,                                  required, the integer 1
      "name": "wall",                               required, a non-empty string (the Blender object name)
      "primitive": {...},                           required, what the mesh was built from (below)
      "vertices": [[x, y, z], ...],                 required, V >= 3 vertex positions, OBJECT space
      "faces": [[i, j, k], ...],                    required, F >= 1 triangles, 0-based indices into vertices;
                                                    counter-clockwise seen from the front (Blender's order,
                                                    front normal = (v_j - v_i) x (v_k - v_i))
      "uvs": [[u, v], ...],                         required, exactly 3*F corner UVs in face order: uvs[3f + c]
                                                    is corner c of face f (Blender's loop UVs of a triangulated
                                                    mesh). u runs left->right and v bottom->top of the image.
      "matrix_world": [[4 numbers] x 4],            required, object -> world, row-major, rows as Blender's
                                                    ``obj.matrix_world`` prints them (translation in the last
                                                    column, last row 0 0 0 1), world = SfM/COLMAP world
      "texture": "wall.png" | null,                 an sRGB-encoded PNG/JPEG (8/16-bit, optional alpha), path
                                                    relative to this JSON file's folder or absolute
      "color": [r, g, b] | null,                    a flat LINEAR RGB colour in [0, 1]
      "opacity": 1.0,                               optional, in [0, 1], multiplies texture alpha (default 1)
      "extension": "REPEAT" | "EXTEND"              optional, texture wrap outside [0,1]^2 as Blender's
                                                    Image Texture node (default "REPEAT", Blender's default)
    }

Exactly one of ``texture`` / ``color`` is non-null. Every number must be finite.

``primitive`` (in object space, so ``matrix_world`` places it like the vertices):

- ``{"type": "mesh"}`` — any mesh.
- ``{"type": "plane", "center": [3], "normal": [3], "u_axis": [3], "v_axis": [3], "size": [w, h]}`` —
  the fitted plane: ``center`` +- ``size/2`` along the unit in-plane axes; UV (0,0) at
  ``center - w/2 u - h/2 v``, (1,1) at the opposite corner; ``normal = u_axis x v_axis``.
  :func:`plane_proxy` writes it with the frame in ``matrix_world`` (local centre 0, axes x, y, z),
  so the Blender object's origin is the plane centre and its local z is the normal.
- ``{"type": "cylinder", "base": [3], "axis": [3], "radius": r, "height": h, "angle_range": [a0, a1]}`` —
  a patch of a cylinder: points ``base + h' axis + r (cos a x_loc + sin a y_loc)`` for ``a`` in
  [a0, a1] (degrees, right-handed about ``axis``) and ``h'`` in [0, h]; u = (a - a0)/(a1 - a0)
  around the axis (or u = (a1 - a)/(a1 - a0) with the optional ``"mirror_u": true``, used when the
  surface is seen from inside), v = h'/h along it. :func:`cylinder_proxy` writes base 0 and axis z in
  object space (``x_loc`` = local x) with the frame in ``matrix_world``.

The primitive is metadata (what the Blender side may show or re-fit); the bake only uses the
triangles, so a moved, scaled or re-painted proxy goes through the same code as any mesh.

Validation (:func:`load_proxy`): every problem is one :class:`IGSError` that names the file and says
what is wrong — unparseable JSON, wrong schema, missing/ill-typed keys, no UVs or a UV count other
than 3*F, face indices out of range, NaN/inf anywhere, a matrix_world that is not an invertible affine
transform, a degenerate triangle (world-space area <= ``DEGENERATE_AREA_RATIO`` (1e-10) times the
squared diagonal of the mesh's bounding box, i.e. scale-free), both or neither of texture/color,
a missing or unreadable texture.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from backend.core.atomic_io import write_image_file, write_json
from backend.core.cameras import POSE_LIMIT, check_pose_values
from backend.core.errors import IGSError
from backend.core.imageio import linear_to_srgb, read_linear
from backend.core.small_reads import read_json
from igs_contract import numbers
from igs_contract.errors import ContractError

PROXY_SCHEMA = 1
DEGENERATE_AREA_RATIO = 1e-10
EXTENSIONS = ("REPEAT", "EXTEND")
PRIMITIVE_TYPES = ("mesh", "plane", "cylinder")


@dataclass
class ProxyMesh:
    """A triangle mesh with corner UVs and a texture or a flat colour, placed in the world."""

    name: str
    """Object name (Blender's)."""
    local_vertices: np.ndarray
    """(V, 3) float64 vertex positions in object space."""
    faces: np.ndarray
    """(F, 3) int64 triangle vertex indices."""
    uvs: np.ndarray
    """(F, 3, 2) float64 UV of each face corner (u right, v up)."""
    matrix_world: np.ndarray = field(default_factory=lambda: np.eye(4))
    """(4, 4) float64 object -> world."""
    texture: np.ndarray | None = None
    """(Ht, Wt, 3) float32 linear RGB, or None when ``color`` is used."""
    texture_alpha: np.ndarray | None = None
    """(Ht, Wt) float32 alpha of the texture in [0, 1], None when the image has no alpha."""
    color: np.ndarray | None = None
    """(3,) float32 flat linear RGB, or None when ``texture`` is used."""
    opacity: float = 1.0
    """Global opacity in [0, 1] (multiplies the texture alpha)."""
    extension: str = "REPEAT"
    """Texture wrap outside [0, 1]^2: "REPEAT" or "EXTEND" (Blender's Image Texture names)."""
    primitive: dict[str, Any] = field(default_factory=lambda: {"type": "mesh"})
    """What the mesh was built from (see the module docstring), object space."""
    texture_path: Path | None = None
    """Where the texture was read from (kept so that saving refers to the same file)."""

    @property
    def vertices(self) -> np.ndarray:
        """(V, 3) float64 world-space vertex positions (``matrix_world`` applied)."""
        m = self.matrix_world
        return self.local_vertices @ m[:3, :3].T + m[:3, 3]

    @property
    def corner_vertices(self) -> np.ndarray:
        """(F, 3, 3) world-space positions of each face's corners."""
        return self.vertices[self.faces]

    def face_normals(self) -> np.ndarray:
        """(F, 3) unit world-space front normals (counter-clockwise winding)."""
        tri = self.corner_vertices
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        return n / np.linalg.norm(n, axis=1, keepdims=True)


# ----------------------------------------------------------------------------------------------
# Building the fitted primitives


def _unit(v: Any, what: str) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64).reshape(3)
    n = np.linalg.norm(v)
    if not np.isfinite(n) or n < 1e-12:
        raise IGSError(f"{what} must be a finite non-zero 3-vector, got {v.tolist()}")
    return v / n


def _frame_matrix(origin: np.ndarray, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, y, z, origin
    return m


def plane_proxy(center, normal, u_axis, v_axis, size, *, name: str = "plane", texture: np.ndarray | None = None,
                texture_alpha: np.ndarray | None = None, color=None, opacity: float = 1.0,
                extension: str = "EXTEND") -> ProxyMesh:
    """The 2-triangle plane ``center +- size/2`` along ``u_axis``/``v_axis`` with UVs covering [0,1]^2.

    ``v_axis`` is re-orthogonalised against ``u_axis`` inside the plane of ``normal``; the winding is
    counter-clockwise seen from the side ``normal`` points to (``normal`` is flipped if needed so
    that ``u x v = normal``). Returns a validated :class:`ProxyMesh` whose ``matrix_world`` holds the
    frame (origin = centre, local x = u, y = v, z = normal). Its UVs span exactly [0,1]^2, so the
    texture ``extension`` defaults to "EXTEND" (no bleeding of the opposite border at the edges).
    """
    c = np.asarray(center, dtype=np.float64).reshape(3)
    n = _unit(normal, "plane normal")
    u = _unit(np.asarray(u_axis, dtype=np.float64) - np.dot(u_axis, n) * n, "plane u_axis (in-plane part)")
    v = np.cross(n, u)
    if np.dot(v, np.asarray(v_axis, dtype=np.float64)) < 0:  # keep the caller's v direction: flip n
        n, v = -n, -v
    w, h = (float(s) for s in np.asarray(size, dtype=np.float64).reshape(2))
    if not (np.isfinite(w) and np.isfinite(h) and w > 0 and h > 0):
        raise IGSError(f"plane size must be two positive numbers, got {[w, h]}")
    local = np.array([[-w / 2, -h / 2, 0.0], [w / 2, -h / 2, 0.0], [w / 2, h / 2, 0.0], [-w / 2, h / 2, 0.0]])
    faces = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)
    corner_uv = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    proxy = ProxyMesh(
        name=name, local_vertices=local, faces=faces, uvs=corner_uv[faces], matrix_world=_frame_matrix(c, u, v, n),
        texture=texture, texture_alpha=texture_alpha, color=None if color is None else np.asarray(color, np.float32),
        opacity=float(opacity), extension=extension,
        primitive={"type": "plane", "center": [0.0, 0.0, 0.0], "normal": [0.0, 0.0, 1.0], "u_axis": [1.0, 0.0, 0.0],
                   "v_axis": [0.0, 1.0, 0.0], "size": [w, h]},
    )
    validate_proxy(proxy, f"plane proxy '{name}'")
    return proxy


def cylinder_proxy(base, axis, radius: float, height: float, angle_range=(0.0, 360.0), segments: int = 64, *,
                   x_dir=None, name: str = "cylinder", texture: np.ndarray | None = None,
                   texture_alpha: np.ndarray | None = None, color=None, opacity: float = 1.0,
                   extension: str = "EXTEND") -> ProxyMesh:
    """A UV-unwrapped cylinder patch: u around ``axis`` over ``angle_range`` (degrees), v along it.

    ``x_dir`` is the direction (perpendicular to ``axis``) of angle 0; angles grow right-handedly
    about ``axis``. ``segments`` quads span the angle range (the count is scaled down for partial
    ranges, at least 2). Front faces point away from the axis. ``matrix_world`` holds the frame
    (origin = ``base``, local x = ``x_dir``, local z = ``axis``).
    """
    b = np.asarray(base, dtype=np.float64).reshape(3)
    a = _unit(axis, "cylinder axis")
    if x_dir is None:
        x_dir = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = _unit(np.asarray(x_dir, dtype=np.float64) - np.dot(x_dir, a) * a, "cylinder x_dir (perpendicular part)")
    y = np.cross(a, x)
    r, h = float(radius), float(height)
    a0, a1 = (float(v) for v in np.asarray(angle_range, dtype=np.float64).reshape(2))
    if not (np.isfinite(r) and r > 0 and np.isfinite(h) and h > 0):
        raise IGSError(f"cylinder radius and height must be positive, got radius={r}, height={h}")
    if not (np.isfinite(a0) and np.isfinite(a1) and 0 < a1 - a0 <= 360.0):
        raise IGSError(f"cylinder angle_range must satisfy a0 < a1 <= a0 + 360, got {[a0, a1]}")
    n_seg = max(2, int(np.ceil(int(segments) * (a1 - a0) / 360.0)))
    ang = np.radians(np.linspace(a0, a1, n_seg + 1))
    ring = np.stack([r * np.cos(ang), r * np.sin(ang)], axis=1)
    bottom = np.concatenate([ring, np.zeros((n_seg + 1, 1))], axis=1)
    top = np.concatenate([ring, np.full((n_seg + 1, 1), h)], axis=1)
    local = np.concatenate([bottom, top])
    k = np.arange(n_seg)
    tb, tt = k, k + n_seg + 1  # bottom / top vertex of column k
    faces = np.concatenate([np.stack([tb, tb + 1, tt + 1], 1), np.stack([tb, tt + 1, tt], 1)]).astype(np.int64)
    us = np.linspace(0.0, 1.0, n_seg + 1)
    vert_uv = np.concatenate([np.stack([us, np.zeros_like(us)], 1), np.stack([us, np.ones_like(us)], 1)])
    proxy = ProxyMesh(
        name=name, local_vertices=local, faces=faces, uvs=vert_uv[faces], matrix_world=_frame_matrix(b, x, y, a),
        texture=texture, texture_alpha=texture_alpha, color=None if color is None else np.asarray(color, np.float32),
        opacity=float(opacity), extension=extension,
        primitive={"type": "cylinder", "base": [0.0, 0.0, 0.0], "axis": [0.0, 0.0, 1.0], "radius": r,
                   "height": h, "angle_range": [a0, a1]},
    )
    validate_proxy(proxy, f"cylinder proxy '{name}'")
    return proxy


# ----------------------------------------------------------------------------------------------
# Validation


def validate_proxy(proxy: ProxyMesh, where: str) -> None:
    """Check an in-memory proxy; ``where`` (a file or a description) starts every error message."""
    v, f, uv, m = proxy.local_vertices, proxy.faces, proxy.uvs, proxy.matrix_world
    if v.ndim != 2 or v.shape[1] != 3 or len(v) < 3:
        raise IGSError(f"{where}: 'vertices' must be a list of at least 3 [x, y, z], got shape {v.shape}")
    if not np.isfinite(v).all():
        raise IGSError(f"{where}: 'vertices' contain NaN or infinite values")
    check_pose_values(v, where, "'vertices'")
    if f.ndim != 2 or f.shape[1] != 3 or len(f) < 1:
        raise IGSError(f"{where}: 'faces' must be a list of at least one triangle [i, j, k], got shape {f.shape}")
    if f.min() < 0 or f.max() >= len(v):
        bad = int(np.argmax((f < 0).any(1) | (f >= len(v)).any(1)))
        raise IGSError(f"{where}: face {bad} {f[bad].tolist()} has a vertex index outside 0..{len(v) - 1}")
    if uv.size == 0:
        raise IGSError(f"{where}: the mesh has no UVs ('uvs' is empty); unwrap it in Blender (U > Unwrap)")
    if uv.shape != (len(f), 3, 2):
        raise IGSError(f"{where}: 'uvs' must hold 3 corner UVs per face (3*{len(f)} = {3 * len(f)} [u, v]), "
                       f"got {uv.size // 2 if uv.ndim and uv.shape[-1] == 2 else uv.shape}")
    if not np.isfinite(uv).all():
        raise IGSError(f"{where}: 'uvs' contain NaN or infinite values")
    if m.shape != (4, 4) or not np.isfinite(m).all():
        raise IGSError(f"{where}: 'matrix_world' must be a finite 4x4 matrix")
    check_pose_values(m, where, "'matrix_world'")
    if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0], atol=1e-6):
        raise IGSError(f"{where}: 'matrix_world' last row must be [0, 0, 0, 1] (an affine transform), got {m[3].tolist()}")
    lin = m[:3, :3]
    scale = max(np.abs(lin).max(), 1e-300)
    if abs(np.linalg.det(lin / scale)) < 1e-9:
        raise IGSError(f"{where}: 'matrix_world' is not invertible (a zero scale?)")
    tri = proxy.corner_vertices
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    world = proxy.vertices
    diag2 = float(np.sum((world.max(0) - world.min(0)) ** 2))
    bad = np.flatnonzero(area <= DEGENERATE_AREA_RATIO * diag2)
    if len(bad):
        raise IGSError(f"{where}: {len(bad)} degenerate triangle(s) (zero area, e.g. face {int(bad[0])} "
                       f"{f[bad[0]].tolist()}); remove them in Blender (Mesh > Clean Up > Degenerate Dissolve)")
    if (proxy.texture is None) == (proxy.color is None):
        raise IGSError(f"{where}: exactly one of 'texture' and 'color' must be set "
                       f"(got {'both' if proxy.texture is not None else 'neither'})")
    if proxy.texture is not None:
        t = proxy.texture
        if t.ndim != 3 or t.shape[2] != 3 or t.shape[0] < 1 or t.shape[1] < 1 or not np.isfinite(t).all():
            raise IGSError(f"{where}: texture must be a finite (H, W, 3) image, got shape {t.shape}")
        if proxy.texture_alpha is not None and proxy.texture_alpha.shape != t.shape[:2]:
            raise IGSError(f"{where}: texture alpha shape {proxy.texture_alpha.shape} != image {t.shape[:2]}")
    if proxy.color is not None:
        c = proxy.color
        if c.shape != (3,) or not np.isfinite(c).all() or c.min() < 0:
            raise IGSError(f"{where}: 'color' must be 3 finite non-negative linear RGB values, got {c.tolist()}")
    if not (np.isfinite(proxy.opacity) and 0.0 <= proxy.opacity <= 1.0):
        raise IGSError(f"{where}: 'opacity' must be in [0, 1], got {proxy.opacity}")
    if proxy.extension not in EXTENSIONS:
        raise IGSError(f"{where}: 'extension' must be one of {list(EXTENSIONS)}, got {proxy.extension!r}")
    _validate_primitive(proxy.primitive, where)


def _validate_primitive(p: Any, where: str) -> None:
    if not isinstance(p, dict) or p.get("type") not in PRIMITIVE_TYPES:
        raise IGSError(f"{where}: 'primitive' must be an object with 'type' one of {list(PRIMITIVE_TYPES)}")
    fields = {"plane": {"center": 3, "normal": 3, "u_axis": 3, "v_axis": 3, "size": 2},
              "cylinder": {"base": 3, "axis": 3, "radius": 0, "height": 0, "angle_range": 2},
              "mesh": {}}[p["type"]]
    for key, n in fields.items():
        val = p.get(key)
        try:
            arr = np.asarray(val, dtype=np.float64)
        except (TypeError, ValueError):
            arr = np.array([np.nan])
        if val is None or arr.shape != ((n,) if n else ()) or not np.isfinite(arr).all():
            want = f"{n} numbers" if n else "a number"
            raise IGSError(f"{where}: primitive {p['type']!r} needs '{key}' as {want}, got {val!r}")


# ----------------------------------------------------------------------------------------------
# Reading and writing


def _json_array(data: dict, key: str, where: str, dtype, inner: int) -> np.ndarray:
    if key not in data:
        raise IGSError(f"{where}: missing key '{key}'")
    val = data[key]
    if not isinstance(val, list):
        raise IGSError(f"{where}: '{key}' must be a list, got {type(val).__name__}")
    if len(val) == 0:
        return np.zeros((0, inner), dtype=dtype)
    try:
        arr = np.array(val, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise IGSError(f"{where}: '{key}' must be a list of [{inner} numbers] ({e})") from e
    if arr.ndim != 2 or arr.shape[1] != inner:
        raise IGSError(f"{where}: '{key}' must be a list of [{inner} numbers], got shape {arr.shape}")
    if dtype is np.int64:
        # within POSE_LIMIT before the cast: a larger number is no index, and would wrap around in it
        if not np.isfinite(arr).all() or (np.abs(arr) > POSE_LIMIT).any() or (arr != np.round(arr)).any():
            raise IGSError(f"{where}: '{key}' must hold integer indices")
        return arr.astype(np.int64)
    return arr


def _read_texture(path: Path, where: str) -> tuple[np.ndarray, np.ndarray | None]:
    if not path.is_file():
        raise IGSError(f"{where}: texture file {path} not found")
    try:
        rgb = read_linear(path)
    except IGSError as e:
        raise IGSError(f"{where}: texture {e}") from e
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    alpha = None
    if raw is not None and raw.ndim == 3 and raw.shape[2] == 4:
        alpha = raw[:, :, 3].astype(np.float32) / (65535.0 if raw.dtype == np.uint16 else 255.0)
    return rgb, alpha


def _json_mesh(data: dict, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(vertices (V, 3), faces (F, 3), corner UVs (3F, 2), matrix_world (4, 4)) of a proxy.json object."""
    vertices = _json_array(data, "vertices", where, np.float64, 3)
    faces = _json_array(data, "faces", where, np.int64, 3)
    if "uvs" not in data or data["uvs"] is None or data["uvs"] == []:
        raise IGSError(f"{where}: the mesh has no UVs ('uvs' missing or empty); unwrap it in Blender (U > Unwrap)")
    uv_flat = _json_array(data, "uvs", where, np.float64, 2)
    if len(uv_flat) != 3 * len(faces):
        raise IGSError(f"{where}: 'uvs' must hold 3 corner UVs per face: {len(faces)} faces need "
                       f"{3 * len(faces)} [u, v], got {len(uv_flat)}")
    if "matrix_world" not in data:
        raise IGSError(f"{where}: missing key 'matrix_world' (4x4, row-major, object -> world)")
    try:
        matrix = np.array(data["matrix_world"], dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise IGSError(f"{where}: 'matrix_world' must be 4 rows of 4 numbers ({e})") from e
    if matrix.shape != (4, 4):
        raise IGSError(f"{where}: 'matrix_world' must be 4 rows of 4 numbers, got shape {matrix.shape}")
    return vertices, faces, uv_flat, matrix


def _json_appearance(data: dict, path: Path, where: str
                     ) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None, Path | None]:
    """(texture (H, W, 3) linear, its alpha (H, W), flat colour (3,), the texture's file) of a proxy.json
    object: exactly one of a texture (read from a path relative to ``path``'s folder) and a colour."""
    tex_ref, color_ref = data.get("texture"), data.get("color")
    if (tex_ref is None) == (color_ref is None):
        raise IGSError(f"{where}: exactly one of 'texture' and 'color' must be non-null "
                       f"(got {'both' if tex_ref is not None else 'neither'})")
    if tex_ref is not None:
        if not isinstance(tex_ref, str) or not tex_ref:
            raise IGSError(f"{where}: 'texture' must be a file path string")
        tex_path = Path(tex_ref) if Path(tex_ref).is_absolute() else path.parent / tex_ref
        texture, alpha = _read_texture(tex_path, where)
        return texture, alpha, None, tex_path
    try:
        color = np.array(color_ref, dtype=np.float32)
    except (TypeError, ValueError) as e:
        raise IGSError(f"{where}: 'color' must be [r, g, b] ({e})") from e
    if color.shape != (3,):
        raise IGSError(f"{where}: 'color' must be [r, g, b], got {color_ref!r}")
    return None, None, color, None


def load_proxy(path: str | os.PathLike) -> ProxyMesh:
    """Read and validate a ``proxy.json`` (format in the module docstring); textures are loaded linear."""
    path = Path(path)
    where = str(path)
    data = read_json(path, "proxy file")
    if not isinstance(data, dict):
        raise IGSError(f"{where}: the top level must be a JSON object")
    try:  # every number, before any becomes an array: a 400-digit one would overflow the conversion
        numbers.check_tree(data, where, numbers.Range(-POSE_LIMIT, POSE_LIMIT))
    except ContractError as e:
        raise IGSError(str(e)) from None
    if data.get("schema") != PROXY_SCHEMA:
        raise IGSError(f"{where}: 'schema' must be {PROXY_SCHEMA}, got {data.get('schema')!r}")
    name = data.get("name")
    if not isinstance(name, str) or not name:
        raise IGSError(f"{where}: 'name' must be a non-empty string")
    if "primitive" not in data:
        raise IGSError(f"{where}: missing key 'primitive' (use {{\"type\": \"mesh\"}} for any mesh)")
    vertices, faces, uv_flat, matrix = _json_mesh(data, where)
    texture, alpha, color, tex_path = _json_appearance(data, path, where)
    try:
        opacity = numbers.check(data.get("opacity", 1.0), f"{where}: 'opacity'", numbers.Range(0.0, 1.0))
    except ContractError as e:
        raise IGSError(str(e)) from None
    proxy = ProxyMesh(
        name=name, local_vertices=vertices, faces=faces,
        uvs=uv_flat.reshape(-1, 3, 2) if len(uv_flat) else np.zeros((0, 3, 2)),
        matrix_world=matrix, texture=texture, texture_alpha=alpha, color=color, opacity=float(opacity),
        extension=data.get("extension", "REPEAT"), primitive=data["primitive"], texture_path=tex_path,
    )
    validate_proxy(proxy, where)
    return proxy


def proxy_to_dict(proxy: ProxyMesh, texture_ref: str | None) -> dict[str, Any]:
    """The JSON object of a proxy; ``texture_ref`` is the path string to store (None with a colour)."""
    return {
        "schema": PROXY_SCHEMA,
        "name": proxy.name,
        "primitive": proxy.primitive,
        "vertices": proxy.local_vertices.tolist(),
        "faces": proxy.faces.tolist(),
        "uvs": proxy.uvs.reshape(-1, 2).tolist(),
        "matrix_world": proxy.matrix_world.tolist(),
        "texture": texture_ref,
        "color": None if proxy.color is None else [float(c) for c in proxy.color],
        "opacity": proxy.opacity,
        "extension": proxy.extension,
    }


def write_texture(path: str | os.PathLike, linear_rgb: np.ndarray, alpha: np.ndarray | None = None) -> None:
    """Write a linear texture as a 16-bit sRGB-encoded PNG (RGBA when ``alpha`` is given), atomically."""
    srgb = linear_to_srgb(linear_rgb)
    chans = [srgb[:, :, 2], srgb[:, :, 1], srgb[:, :, 0]]  # OpenCV wants BGR(A)
    if alpha is not None:
        chans.append(np.clip(np.asarray(alpha, np.float32), 0.0, 1.0))
    data = (np.stack(chans, axis=2) * 65535.0 + 0.5).astype(np.uint16)
    write_image_file(path, data)


def save_proxy(path: str | os.PathLike, proxy: ProxyMesh) -> Path:
    """Write ``proxy`` as ``path`` (JSON, atomically) after validating it.

    A texture read from a file keeps referring to that file (relative to the JSON's folder when it
    lies under it); an in-memory texture is written beside the JSON as ``<stem>.png`` (16-bit sRGB).
    Returns the JSON path.
    """
    path = Path(path)
    validate_proxy(proxy, f"proxy '{proxy.name}' (saving to {path})")
    tex_ref = None
    if proxy.texture is not None:
        if proxy.texture_path is None or not Path(proxy.texture_path).is_file():
            tex_file = path.with_suffix(".png")
            write_texture(tex_file, proxy.texture, proxy.texture_alpha)
            proxy.texture_path = tex_file
        tex_file = Path(proxy.texture_path).resolve()
        try:
            tex_ref = tex_file.relative_to(path.parent.resolve()).as_posix()
        except ValueError:
            tex_ref = str(tex_file)
    write_json(path, proxy_to_dict(proxy, tex_ref))
    return path
