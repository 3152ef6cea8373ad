"""Edit proxies: ``proxy.json`` <-> a textured mesh object the artist moves with Blender's gizmos.

The file format is the backend's (``backend/edit/proxy.py`` documents it): schema 1, ``name``,
``primitive`` (plane / cylinder / mesh, object space), ``vertices`` (object space), triangle
``faces``, one UV per face corner (``uvs[3f + c]``, Blender's loop UVs), ``matrix_world``
(object -> SfM world, row-major), and exactly one of ``texture`` (sRGB image path, relative to the
JSON or absolute) / ``color`` (linear RGB), optional ``opacity`` and ``extension`` (REPEAT/EXTEND).

Any mesh with UVs can be a proxy (a fitted plane or cylinder is one case): triangles are taken
from Blender's loop triangles, so quads and n-gons are fine. Only bpy and json are used here.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import bpy
import numpy as np
from mathutils import Matrix

from ..igs_contract import small_file
from ..igs_contract.errors import ContractError
from . import compat, scene_objects
from .errors import UserError

SCHEMA = 1
COLLECTION = "IGS Edits"
IMAGE_NODE = "IGS texture"
BSDF_NODE = "IGS surface"


def proxy_object_name(edit: str) -> str:
    return f"IGS proxy [{edit}]"


def read_proxy_json(path: str | os.PathLike) -> dict[str, Any]:
    """Read a proxy file and check what the mesh needs (the backend validates the rest at bake time)."""
    path = Path(path)
    try:
        data = small_file.read_json(path, "proxy file")
    except ContractError as e:
        raise UserError(str(e)) from None
    if not isinstance(data, dict) or data.get("schema") != SCHEMA:
        raise UserError(f"{path}: not a schema-{SCHEMA} proxy file")
    for key in ("name", "vertices", "faces", "uvs", "matrix_world"):
        if key not in data:
            raise UserError(f"{path}: missing key '{key}'")
    try:
        verts = np.asarray(data["vertices"], dtype=np.float64).reshape(-1, 3)
        faces = np.asarray(data["faces"], dtype=np.int64).reshape(-1, 3)
        uvs = np.asarray(data["uvs"], dtype=np.float64).reshape(-1, 2)
        matrix = np.asarray(data["matrix_world"], dtype=np.float64).reshape(4, 4)
    except (TypeError, ValueError) as e:
        raise UserError(f"{path}: vertices/faces/uvs/matrix_world have the wrong shape ({e})") from e
    if len(faces) == 0 or faces.min() < 0 or faces.max() >= len(verts):
        raise UserError(f"{path}: faces must be triangles indexing the {len(verts)} vertices")
    if len(uvs) != 3 * len(faces):
        raise UserError(f"{path}: {len(faces)} faces need {3 * len(faces)} corner UVs, the file has {len(uvs)}")
    if not (np.isfinite(verts).all() and np.isfinite(uvs).all() and np.isfinite(matrix).all()):
        raise UserError(f"{path}: NaN or infinite numbers in the proxy")
    data["_arrays"] = (verts, faces, uvs, matrix)
    return data


def texture_path(data: dict[str, Any], json_path: Path) -> Path | None:
    ref = data.get("texture")
    if not ref:
        return None
    p = Path(ref)
    return p if p.is_absolute() else json_path.parent / p


def proxy_material(name: str) -> bpy.types.Material:
    """A material for a proxy: Principled BSDF whose Base Color comes from an image texture node."""
    mat, nodes, links, out = compat.emptied_node_material(name)
    bsdf = nodes.new("ShaderNodeBsdfPrincipled")
    bsdf.name = BSDF_NODE
    tex = nodes.new("ShaderNodeTexImage")
    tex.name = IMAGE_NODE
    tex.location, bsdf.location, out.location = (-400, 0), (0, 0), (300, 0)
    links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    nodes.active = tex  # Texture Paint paints the active image node
    return mat


def _nodes(obj: bpy.types.Object):
    mat = obj.active_material
    if mat is None or mat.node_tree is None:
        raise UserError(f"'{obj.name}' has no proxy material; use Texture to assign an image or a colour")
    nodes = mat.node_tree.nodes
    return mat, nodes.get(BSDF_NODE) or next((n for n in nodes if n.type == "BSDF_PRINCIPLED"), None), \
        nodes.get(IMAGE_NODE) or next((n for n in nodes if n.type == "TEX_IMAGE"), None)


def set_proxy_image(obj: bpy.types.Object, image: bpy.types.Image, extension: str = "REPEAT") -> None:
    """Texture the proxy with ``image`` (linked to Base Color, its alpha to Alpha)."""
    _ensure_material(obj)
    mat, bsdf, tex = _nodes(obj)
    if tex is None:
        tex = mat.node_tree.nodes.new("ShaderNodeTexImage")
        tex.name = IMAGE_NODE
    tex.image = image
    tex.extension = extension
    links = mat.node_tree.links
    links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    links.new(tex.outputs["Alpha"], bsdf.inputs["Alpha"])
    mat.node_tree.nodes.active = tex
    obj["igs_texture_mode"] = "IMAGE"


def set_proxy_color(obj: bpy.types.Object, rgb) -> None:
    """A flat linear colour instead of a texture (the image node stays, unlinked, for painting)."""
    _ensure_material(obj)
    mat, bsdf, tex = _nodes(obj)
    for link in list(bsdf.inputs["Base Color"].links) + list(bsdf.inputs["Alpha"].links):
        mat.node_tree.links.remove(link)
    bsdf.inputs["Base Color"].default_value = (*[float(c) for c in rgb[:3]], 1.0)
    bsdf.inputs["Alpha"].default_value = 1.0
    obj["igs_texture_mode"] = "COLOR"


def _ensure_material(obj: bpy.types.Object) -> None:
    if obj.active_material is None or obj.active_material.node_tree is None:
        mat = proxy_material(f"IGS proxy material [{obj.get('igs_edit', obj.name)}]")
        obj.data.materials.clear()
        obj.data.materials.append(mat)


def proxy_image(obj: bpy.types.Object) -> bpy.types.Image | None:
    """The image the proxy shows, or None when it shows a flat colour."""
    if obj.get("igs_texture_mode") == "COLOR":
        return None
    mat, bsdf, tex = _nodes(obj)
    if tex is None or tex.image is None or bsdf is None:
        return None
    if not any(link.from_node == tex for link in bsdf.inputs["Base Color"].links):
        return None
    return tex.image


def proxy_color(obj: bpy.types.Object) -> list[float]:
    _, bsdf, _ = _nodes(obj)
    return [float(c) for c in bsdf.inputs["Base Color"].default_value[:3]]


def create_proxy_object(json_path: str | os.PathLike, edit: str) -> bpy.types.Object:
    """Build (or rebuild) the mesh object of edit ``edit`` from its proxy file."""
    json_path = Path(json_path)
    data = read_proxy_json(json_path)
    verts, faces, uvs, matrix = data["_arrays"]
    name = proxy_object_name(edit)
    old = bpy.data.objects.get(name)
    scene_objects.remove_object(old)
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts.tolist(), [], faces.tolist())
    uv_layer = mesh.uv_layers.new(name="UVMap")
    # from_pydata keeps the face and corner order, so loop 3f + c is corner c of face f.
    loop_uvs = np.zeros((len(mesh.loops), 2), dtype=np.float32)
    for poly in mesh.polygons:
        loop_uvs[poly.loop_start:poly.loop_start + 3] = uvs[3 * poly.index:3 * poly.index + 3]
    uv_layer.uv.foreach_set("vector", loop_uvs.ravel())
    mesh.validate(clean_customdata=False)  # after the UVs: validation may drop a degenerate face
    obj = bpy.data.objects.new(name, mesh)
    scene_objects.collection(COLLECTION).objects.link(obj)
    scene_objects.parent_to_root(obj, Matrix(matrix.tolist()))
    obj["igs_edit"] = edit
    obj["igs_proxy"] = str(json_path)
    obj["igs_primitive"] = json.dumps(data.get("primitive", {"type": "mesh"}))
    obj["igs_vertex_count"] = len(verts)
    mat = proxy_material(f"IGS proxy material [{edit}]")
    mesh.materials.append(mat)
    tex = texture_path(data, json_path)
    extension = data.get("extension", "REPEAT") if data.get("extension") in ("REPEAT", "EXTEND") else "REPEAT"
    if tex is not None and tex.is_file():
        set_proxy_image(obj, bpy.data.images.load(str(tex), check_existing=True), extension)
    elif data.get("color") is not None:
        set_proxy_color(obj, data["color"])
    else:
        set_proxy_color(obj, (0.8, 0.8, 0.8))
    bpy.context.view_layer.update()  # matrix_world from the parent and matrix_basis
    return obj


def adopt_mesh_as_proxy(obj: bpy.types.Object, edit: str) -> None:
    """Make any mesh with UVs the proxy of edit ``edit`` (its material gains the proxy nodes if needed)."""
    if obj.type != "MESH":
        raise UserError(f"'{obj.name}' is a {obj.type.lower()}, not a mesh")
    if not obj.data.uv_layers:
        raise UserError(f"'{obj.name}' has no UVs; unwrap it first (Edit Mode > U > Unwrap)")
    if not obj.data.polygons:
        raise UserError(f"'{obj.name}' has no faces")
    obj["igs_edit"] = edit
    obj["igs_primitive"] = json.dumps({"type": "mesh"})
    obj["igs_vertex_count"] = len(obj.data.vertices)
    try:
        _nodes(obj)
    except UserError:
        _ensure_material(obj)
        set_proxy_color(obj, (0.8, 0.8, 0.8))
        return
    mat, bsdf, _ = _nodes(obj)
    if bsdf is None:
        _ensure_material(obj)
        set_proxy_color(obj, (0.8, 0.8, 0.8))


def proxy_dict(obj: bpy.types.Object, edit: str, texture_ref: str | None, color=None) -> dict[str, Any]:
    """The proxy file content for the object as it is now (moved, scaled, re-textured).

    ``matrix_world`` is in SfM coordinates (the capture root's transform removed). Exactly one of
    ``texture_ref`` (path string to store) and ``color`` is used; with neither, the material's colour.
    """
    if obj.type != "MESH":
        raise UserError(f"'{obj.name}' is not a mesh")
    mesh = obj.data
    uv_layer = mesh.uv_layers.active
    if uv_layer is None:
        raise UserError(f"'{obj.name}' has no UVs; unwrap it first (Edit Mode > U > Unwrap)")
    if obj.mode == "EDIT":
        obj.update_from_editmode()
    mesh.calc_loop_triangles()
    ntri = len(mesh.loop_triangles)
    if ntri == 0:
        raise UserError(f"'{obj.name}' has no faces")
    verts = np.empty(len(mesh.vertices) * 3, dtype=np.float64)
    mesh.vertices.foreach_get("co", verts)
    tri_verts = np.empty(ntri * 3, dtype=np.int64)
    mesh.loop_triangles.foreach_get("vertices", tri_verts)
    tri_loops = np.empty(ntri * 3, dtype=np.int64)
    mesh.loop_triangles.foreach_get("loops", tri_loops)
    loop_uv = np.empty(len(mesh.loops) * 2, dtype=np.float64)
    uv_layer.uv.foreach_get("vector", loop_uv)
    corner_uv = loop_uv.reshape(-1, 2)[tri_loops]
    primitive = json.loads(obj.get("igs_primitive", '{"type": "mesh"}'))
    if int(obj.get("igs_vertex_count", -1)) != len(mesh.vertices):
        primitive = {"type": "mesh"}  # the artist edited the geometry: the primitive no longer describes it
    data: dict[str, Any] = {
        "schema": SCHEMA,
        "name": edit,
        "primitive": primitive,
        "vertices": verts.reshape(-1, 3).tolist(),
        "faces": tri_verts.reshape(-1, 3).tolist(),
        "uvs": corner_uv.tolist(),
        "matrix_world": scene_objects.to_capture_space(obj.matrix_world).tolist(),
        "texture": None,
        "color": None,
    }
    if texture_ref is not None:
        data["texture"] = texture_ref
        mat, _, tex = _nodes(obj)
        if tex is not None and tex.extension in ("REPEAT", "EXTEND"):
            data["extension"] = tex.extension
    else:
        rgb = color if color is not None else proxy_color(obj)
        data["color"] = [max(0.0, float(c)) for c in rgb[:3]]
    return data


def texture_file_for_bake(obj: bpy.types.Object, edit_dir: Path) -> Path | None:
    """The image file the bake should read: the proxy image's file, or a PNG saved into ``edit_dir``
    when the image only lives in Blender (painted, generated, packed or modified); None for a colour.

    A painted image whose file lies in ``edit_dir`` (Paint's ``paint.png``) is saved in place; other
    modified images go to ``edit_dir/texture.png`` as a copy, so the artist's own files are never
    overwritten and Blender still counts the image as unsaved."""
    image = proxy_image(obj)
    if image is None:
        return None
    src = Path(bpy.path.abspath(image.filepath)) if image.filepath else None
    file_backed = image.source == "FILE" and src is not None and image.packed_file is None
    if file_backed and src.is_file() and not image.is_dirty:
        return src
    if image.size[0] == 0 or image.size[1] == 0:
        raise UserError(f"image '{image.name}' of '{obj.name}' has no pixels")
    if file_backed and image.is_dirty and src.suffix.lower() == ".png" and src.parent.resolve() == edit_dir.resolve():
        image.save()  # Paint's own file: the painting is kept on disk as well
        return src
    edit_dir.mkdir(parents=True, exist_ok=True)
    out = edit_dir / "texture.png"
    save_srgb_png(image, out)
    if image.source == "GENERATED":  # from now on the image is that file (the painting survives reopening)
        image.filepath = str(out)
        image.source = "FILE"
        if image.is_float:
            image.colorspace_settings.name = "sRGB"  # re-reads the file as sRGB: the same linear pixels
    return out


def save_srgb_png(image: bpy.types.Image, path: Path) -> None:
    """Write ``image``'s pixels to ``path`` as the sRGB PNG the backend reads, leaving the image as it is
    (still unsaved for Blender, same file and format: saving it directly would mark it clean and would use
    its own format and colour space, e.g. OpenEXR or linear bytes for a packed float image)."""
    w, h = image.size
    c = image.channels  # 4 for almost every image; float images read from some files have 1 or 3
    raw = np.empty(w * h * c, dtype=np.float32)
    image.pixels.foreach_get(raw)
    raw = raw.reshape(-1, c)
    pixels = np.ones((w * h, 4), dtype=np.float32)
    pixels[:, :3] = raw[:, :3] if c >= 3 else raw[:, :1]
    if c in (2, 4):
        pixels[:, 3] = raw[:, -1]
    tmp = bpy.data.images.new(".IGS bake texture", w, h, alpha=True, float_buffer=image.is_float)
    try:
        if image.is_float:
            # Float pixels are scene-linear: encode them here (16-bit PNG) and save them untouched
            # ("Non-Color"). Blender's own encoding on save changed meaning in 5.3 (an "sRGB" float image
            # is written as it is there), so it is not relied on.
            tmp.colorspace_settings.name = "Non-Color"
            pixels[:, :3] = srgb_encode(pixels[:, :3])
        tmp.pixels.foreach_set(pixels.ravel())  # byte pixels are already the image's sRGB bytes
        tmp.file_format = "PNG"
        tmp.save(filepath=str(path))
    finally:
        bpy.data.images.remove(tmp)


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """The sRGB transfer function of linear values, clipped to [0, 1] first (a PNG holds no more)."""
    x = np.clip(linear, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055).astype(np.float32)


def write_proxy_json(path: str | os.PathLike, data: dict[str, Any]) -> Path:
    """Write atomically (temp name in the same folder, then rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    clean = {k: v for k, v in data.items() if not k.startswith("_")}
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(clean, indent=1) + "\n", encoding="utf-8")
    os.replace(tmp, path)
    return path


def texture_ref(texture: Path, json_path: Path) -> str:
    """Path string for the JSON: relative when the texture sits beside (or below) the proxy file."""
    try:
        return str(texture.resolve().relative_to(json_path.parent.resolve()))
    except ValueError:
        return str(texture.resolve())
