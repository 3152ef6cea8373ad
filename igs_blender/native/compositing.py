"""Blender renders A x S + R itself (Blender 5.3+): one view layer per field and a compositor group.

:func:`setup` makes the scene's render (F12, Ctrl+F12, any camera, EEVEE or Cycles, the scene's own
resolution and output settings) the composite of the native splat fields (:mod:`.splats`):

- view layer "IGS Albedo": the albedo field (or the selected edit's baked albedo); everything else in
  the scene is a holdout, so a mesh in front of the albedo cuts it out;
- "IGS Shading": the shading field alone (no holdouts: it only multiplies the albedo);
- "IGS Residual": the residual field, the scene's objects as holdouts;
- "IGS Scene": the artist's meshes (and any other object, lit by the scene's lights), with the albedo
  splats as a holdout, so a wall hides what stands behind it;
- "IGS Edit Preview" (only while the selected edit is not baked yet): its proxy, unlit, showing its
  texture or colour (an override material), the scene's objects as holdouts;
- "IGS Lit" (only while the lights collection holds a visible light): the albedo splats lit by those
  lights, ``A x S_new`` (:mod:`.lighting`; their lit copy, flattened onto the normals), the scene's objects
  as holdouts that cast shadows;
- "IGS Occlusion" and "IGS Occlusion Open" (only while a mesh of the artist's renders): the captured shading's
  ambient occlusion with and without the meshes; their ratio O scales the captured shading;
- "IGS Direct" and "IGS Direct Open" (the same while, when the lamps agree with S): the albedo splats' lit copy lit
  by the capture's estimated lamps (:mod:`.captured_lights`, which light the artist's meshes in "IGS Scene") with
  and without the meshes; the part of S the lamps explain, ``d = min(S, Direct Open)``, takes their ratio D where
  it is below O.

The compositor effect "IGS Render" feeds the view layers into the node group "IGS Composite"
(editable, like any node group) which computes, per pixel,
``Image = A' * (S * O + d * min(D - O, 0)) + Lit + R + Scene`` with ``A'`` the albedo with the edit preview laid over it where the
proxy is in front of (or within ``Depth Tolerance`` of) the albedo's depth, as the viewport engine
does. The fields are rendered over black, so the Scene layer (held out by the albedo) adds to the
composite; A and R, held out by the meshes, are zero where a mesh covers them. The group's outputs
Image, Albedo, Shading and Residual are what Render > Layer picks for the output.

Which objects a view layer sees is set per collection (``exclude`` / ``holdout``), since those are
per view layer; objects lying directly in the Scene Collection cannot be, so :func:`setup` moves them
into the collection :data:`SCENE_OBJECTS`. The film is transparent (each field over black) and the
view transform "Standard", so the PNG Blender writes is what ``igs render`` writes.
"""

from __future__ import annotations

import json

import bpy

from .. import camera_objects, compat, layers, lights, proxies, scene_objects
from ..app_handlers import add_depsgraph_handler, remove_depsgraph_handler
from . import captured_lights
from . import lighting as native_lighting
from . import splats as native_splats

VIEW_LAYERS = {"albedo": "IGS Albedo", "shading": "IGS Shading", "residual": "IGS Residual", "scene": "IGS Scene",
               "edit": "IGS Edit Preview", "lit": "IGS Lit", "occluded": "IGS Occlusion",
               "open": "IGS Occlusion Open", "direct": "IGS Direct", "direct_open": "IGS Direct Open"}
TREE = "IGS Render"
GROUP = "IGS Composite"
OVERRIDE = "IGS Edit Preview"
SCENE_OBJECTS = "Scene Objects"
DEPTH_TOLERANCE = 0.03
"""Relative depth within which the proxy counts as on the albedo's surface (the viewport engine's)."""
OUTPUTS = {"full": "Image", "A": "Albedo", "S": "Shading", "R": "Residual"}
"""Render > Layer -> the group output that becomes the render."""
FAR = 1e10
"""Depth of an empty pixel (Blender's)."""

# What each view layer does with a collection: include, exclude or hold out. "field:<f>" is a field's
# collection, "edits" the proxies', "scene" every collection that is not the add-on's, "lights" the lights
# collection (as "scene" unless a role says otherwise: the direct layers leave the added lights out).
ROLES = {
    "albedo": {"field:albedo": "in", "fields": "out", "edits": "out", "scene": "hold"},
    "shading": {"field:shading": "in", "fields": "out", "edits": "out", "scene": "out"},
    "residual": {"field:residual": "in", "fields": "out", "edits": "out", "scene": "hold"},
    "scene": {"field:albedo": "hold", "field:shadow": "in", "field:environment": "in", "field:captured": "in",
              "fields": "out", "edits": "out", "scene": "in"},
    "edit": {"fields": "out", "edits": "in", "scene": "hold"},
    "lit": {"field:lit": "in", "field:shadow": "in", "fields": "out", "edits": "out", "scene": "hold"},
    "occluded": {"field:albedo": "in", "fields": "out", "edits": "out", "scene": "hold"},
    "open": {"field:albedo": "in", "fields": "out", "edits": "out", "scene": "out"},
    "direct": {"field:lit": "in", "field:captured": "in", "field:shadow": "in", "fields": "out", "edits": "out",
               "scene": "hold", "lights": "out"},
    "direct_open": {"field:lit": "in", "field:captured": "in", "field:shadow": "in", "fields": "out",
                    "edits": "out", "scene": "out", "lights": "out"},
}


def is_set_up(scene: bpy.types.Scene) -> bool:
    return scene.view_layers.get(VIEW_LAYERS["albedo"]) is not None


def _own_collections(scene: bpy.types.Scene | None = None) -> dict[str, str]:
    """Collection name -> what it is for the view layers: ``field:<f>``, ``edits``, ``add-on`` (a folder of
    the add-on's whose children decide), or ``lights`` (``scene``'s lights collection)."""
    kinds = {native_splats.field_collection_name(f): f"field:{f}"
             for f in (*native_splats.FIELDS, native_lighting.SHADOW_FIELD, native_lighting.LIT_FIELD,
                       native_lighting.ENVIRONMENT_FIELD, captured_lights.FIELD)}
    kinds.update({proxies.COLLECTION: "edits", scene_objects.COLLECTION_NAME: "add-on", layers.COLLECTION: "add-on",
                  camera_objects.COLLECTION: "add-on"})
    mine = lights.collection(scene.igs) if scene is not None else None
    if mine is not None and mine.name not in kinds:
        kinds[mine.name] = "lights"
    return kinds


def _state(role: str, kind: str) -> str:
    rules = ROLES[role]
    if kind.startswith("field:"):
        return rules.get(kind, rules["fields"])
    if kind == "lights":
        return rules.get(kind, rules.get("scene", "in"))
    return rules.get(kind, "in")


def _apply(layer_coll: bpy.types.LayerCollection, role: str, own: dict[str, str]) -> None:
    """Set exclude/holdout below ``layer_coll`` for the view layer's role (recursively into the add-on's folders)."""
    for child in layer_coll.children:
        kind = own.get(child.collection.name, "scene")
        if kind == "add-on":
            child.exclude = False
            child.holdout = False
            _apply(child, role, own)
            continue
        state = _state(role, kind)
        if child.exclude != (state == "out"):
            child.exclude = state == "out"
        if state != "out" and child.holdout != (state == "hold"):
            child.holdout = state == "hold"


def loose_objects(scene: bpy.types.Scene) -> list[bpy.types.Object]:
    """Objects lying directly in the Scene Collection (no view layer can tell them apart)."""
    return [o for o in scene.collection.objects if o.type not in {"CAMERA"}]


def render_edit(props):
    """The edit the render uses (Render > Use Selected Edit): the one selected in the Edit panel, or None."""
    if not props.render_edit or not 0 <= props.edits_index < len(props.edits):
        return None
    return props.edits[props.edits_index]


def preview_proxy(props):
    """The proxy the render previews over the albedo: the selected edit's, while it is shown and not baked."""
    item = render_edit(props)
    if item is None or item.albedo is not None or item.proxy is None or not item.visible:
        return None
    return item.proxy if item.proxy.type == "MESH" else None


def _override_material(proxy) -> bpy.types.Material:
    """Unlit proxy: its image (its alpha times the proxy's opacity) or its flat colour, as an emission."""
    mat, nodes, links, out = compat.emptied_node_material(OVERRIDE)
    emission = nodes.new("ShaderNodeEmission")
    clear = nodes.new("ShaderNodeBsdfTransparent")
    mix = nodes.new("ShaderNodeMixShader")
    alpha = nodes.new("ShaderNodeMath")
    alpha.operation = "MULTIPLY"
    alpha.inputs[1].default_value = float(proxy.get("igs_opacity", 1.0))
    image = proxies.proxy_image(proxy)
    if image is not None:
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = image
        _, _, own = proxies._nodes(proxy)
        tex.extension = own.extension if own is not None else "REPEAT"
        links.new(tex.outputs["Color"], emission.inputs["Color"])
        links.new(tex.outputs["Alpha"], alpha.inputs[0])
        tex.location = (-500, 0)
    else:
        emission.inputs["Color"].default_value = (*proxies.proxy_color(proxy)[:3], 1.0)
        alpha.inputs[0].default_value = 1.0
    links.new(alpha.outputs[0], mix.inputs["Fac"])
    links.new(clear.outputs["BSDF"], mix.inputs[1])
    links.new(emission.outputs["Emission"], mix.inputs[2])
    links.new(mix.outputs["Shader"], out.inputs["Surface"])
    for i, node in enumerate((alpha, emission, clear, mix, out)):
        node.location = (200 * i - 250, -150 * (i % 2))
    return mat


# -- the compositor group ---------------------------------------------------------------------------------------


def _socket(tree, name: str, in_out: str, socket_type: str, default=None):
    item = tree.interface.new_socket(name, in_out=in_out, socket_type=socket_type)
    if default is not None:
        item.default_value = default
    return item


def composite_group() -> bpy.types.NodeTree:
    """The node group "IGS Composite" (made once; an artist's changes to it are kept)."""
    group = bpy.data.node_groups.get(GROUP)
    if group is not None and group.bl_idname == "CompositorNodeTree":
        if any(i.in_out == "INPUT" and i.name == "Direct Open" for i in group.interface.items_tree):
            return group
        group.name = f"{GROUP} (older)"  # made by an earlier version: kept beside the new one
    group = bpy.data.node_groups.new(GROUP, "CompositorNodeTree")
    for name, kind, default in (("Albedo", "NodeSocketColor", (0, 0, 0, 0)), ("Albedo Depth", "NodeSocketFloat", FAR),
                                ("Shading", "NodeSocketColor", (0, 0, 0, 0)),
                                ("Residual", "NodeSocketColor", (0, 0, 0, 0)),
                                ("Scene", "NodeSocketColor", (0, 0, 0, 0)), ("Edit", "NodeSocketColor", (0, 0, 0, 0)),
                                ("Lit", "NodeSocketColor", (0, 0, 0, 0)),
                                ("Occluded", "NodeSocketColor", (1, 1, 1, 1)), ("Open", "NodeSocketColor", (1, 1, 1, 1)),
                                ("Direct", "NodeSocketColor", (0, 0, 0, 0)),
                                ("Direct Open", "NodeSocketColor", (0, 0, 0, 0)),
                                ("Edit Depth", "NodeSocketFloat", FAR),
                                ("Depth Tolerance", "NodeSocketFloat", DEPTH_TOLERANCE)):
        _socket(group, name, "INPUT", kind, default)
    for name in OUTPUTS.values():
        _socket(group, name, "OUTPUT", "NodeSocketColor")
    nodes, links = group.nodes, group.links
    gin, gout = nodes.new("NodeGroupInput"), nodes.new("NodeGroupOutput")
    gin.location, gout.location = (-1200, 0), (1000, 0)

    def node(kind: str, x: int, y: int, **settings):
        n = nodes.new(kind)
        n.location = (x, y)
        for key, value in settings.items():
            setattr(n, key, value)
        return n

    def math(op: str, a, b, x: int, y: int):
        n = node("ShaderNodeMath", x, y, operation=op)
        for i, v in enumerate((a, b)):
            if isinstance(v, bpy.types.NodeSocket):
                links.new(v, n.inputs[i])
            else:
                n.inputs[i].default_value = v
        return n.outputs[0]

    def vmath(op: str, a, b, x: int, y: int, scale=None):
        n = node("ShaderNodeVectorMath", x, y, operation=op)
        for i, v in enumerate((a, b)):
            if isinstance(v, bpy.types.NodeSocket):
                links.new(v, n.inputs[i])
            elif isinstance(v, tuple):
                n.inputs[i].default_value = v
            elif v is not None:
                n.inputs[i].default_value = (v,) * 3
        if scale is not None:
            links.new(scale, n.inputs["Scale"])
        return n.outputs["Vector"]

    sep_a = node("CompositorNodeSeparateColor", -900, 300)
    links.new(gin.outputs["Albedo"], sep_a.inputs[0])
    sep_p = node("CompositorNodeSeparateColor", -900, -300)
    links.new(gin.outputs["Edit"], sep_p.inputs[0])
    # the proxy shows where it is in front of the albedo, or on its surface (within the tolerance)
    limit = math("MULTIPLY", gin.outputs["Albedo Depth"], math("ADD", gin.outputs["Depth Tolerance"], 1.0, -900, 0),
                 -700, 0)
    front = math("LESS_THAN", gin.outputs["Edit Depth"], limit, -500, 0)
    mask = math("MULTIPLY", front, sep_p.outputs["Alpha"], -300, 0)
    # its straight colour, over the albedo's coverage (a proxy beyond the albedo's edge stays in it)
    inv = math("DIVIDE", 1.0, math("MAXIMUM", sep_p.outputs["Alpha"], 1e-6, -700, -300), -500, -300)
    cover = math("MAXIMUM", sep_a.outputs["Alpha"], sep_p.outputs["Alpha"], -500, -450)
    shown = vmath("SCALE", vmath("SCALE", gin.outputs["Edit"], None, -300, -300, scale=inv), None, -100, -300,
                  scale=cover)
    albedo = node("ShaderNodeMix", 0, 0, data_type="VECTOR", clamp_factor=True)
    links.new(mask, albedo.inputs["Factor"])
    links.new(gin.outputs["Albedo"], albedo.inputs[4])
    links.new(shown, albedo.inputs[5])
    # S times the share of its surroundings the artist's meshes leave open (1 without meshes or albedo)
    sep_o = node("CompositorNodeSeparateColor", -900, -600)
    links.new(gin.outputs["Occluded"], sep_o.inputs[0])
    sep_n = node("CompositorNodeSeparateColor", -900, -750)
    links.new(gin.outputs["Open"], sep_n.inputs[0])
    share = math("DIVIDE", sep_o.outputs["Red"], math("MAXIMUM", sep_n.outputs["Red"], 1e-4, -700, -750), -500, -650)
    seen = math("GREATER_THAN", sep_n.outputs["Red"], 1e-3, -500, -800)
    share = math("ADD", math("MULTIPLY", math("MINIMUM", share, 1.0, -300, -650), seen, -100, -650),
                 math("SUBTRACT", 1.0, seen, -300, -800), 50, -700)
    shading = vmath("SCALE", gin.outputs["Shading"], None, 150, -300, scale=share)
    # the part of S the capture's estimated lamps give, d = min(S, Direct Open), takes their shadows' ratio D
    # instead of O where darker: S * O + d * min(D - O, 0) (d = 0 without lamps, where Direct Open is 0)
    d = vmath("MINIMUM", gin.outputs["Shading"], gin.outputs["Direct Open"], -100, -1000)
    ratio = vmath("DIVIDE", gin.outputs["Direct"], vmath("MAXIMUM", gin.outputs["Direct Open"], 1e-4, -300, -1100),
                  -100, -1100)
    lamps = vmath("SUBTRACT", vmath("MINIMUM", ratio, 1.0, 50, -1100), vmath("SCALE", (1.0, 1.0, 1.0), None, 50, -950,
                                                                             scale=share), 200, -1000)
    lamps = vmath("MINIMUM", lamps, 0.0, 275, -1000)  # a lamp's shadow only darkens beyond O, never undoes it
    shading = vmath("ADD", shading, vmath("MULTIPLY", d, lamps, 350, -1000), 450, -700)
    product = vmath("MULTIPLY", albedo.outputs[1], shading, 250, 0)
    # A * (S + S_new) = A * S + Lit, Lit the albedo splats lit by the lights collection (native_lighting)
    lit = vmath("ADD", product, gin.outputs["Lit"], 350, 100)
    full = vmath("ADD", vmath("ADD", lit, gin.outputs["Residual"], 450, 0), gin.outputs["Scene"], 650, 0)
    # every output opaque over black, as igs render writes its PNGs (a vector becomes an opaque colour)
    links.new(full, gout.inputs["Image"])
    links.new(albedo.outputs[1], gout.inputs["Albedo"])
    links.new(vmath("ADD", gin.outputs["Shading"], 0.0, 650, -200), gout.inputs["Shading"])
    links.new(vmath("ADD", gin.outputs["Residual"], 0.0, 650, -350), gout.inputs["Residual"])
    return group


def _render_tree(scene: bpy.types.Scene) -> bpy.types.NodeTree:
    """The effect's tree: a Render Layers node per view layer into the group, the chosen output out."""
    tree = compat.compositor_tree(scene, TREE)
    nodes = tree.nodes
    if not any(i.in_out == "OUTPUT" and i.name == "Image" for i in tree.interface.items_tree):
        _socket(tree, "Image", "OUTPUT", "NodeSocketColor")
    group = nodes.get(GROUP)
    if group is None:
        group = nodes.new("CompositorNodeGroup")
        group.name = GROUP
        group.location = (300, 0)
    group.node_tree = composite_group()
    out = nodes.get("IGS Output") or nodes.new("NodeGroupOutput")
    out.name = "IGS Output"
    out.location = (600, 0)
    for i, layer in enumerate(VIEW_LAYERS.values()):
        rl = nodes.get(layer)
        if rl is None:
            rl = nodes.new("CompositorNodeRLayers")
            rl.name = layer
            rl.label = layer
            rl.location = (-200, 400 - 250 * i)
        rl.scene = scene
        rl.layer = layer
    return tree


def _wire(scene: bpy.types.Scene, previewing: bool, lighting: bool, occluding: bool = False) -> None:
    """(Re)link the Render Layers to the group, and the group output Render > Layer picks to the tree's output."""
    tree = _render_tree(scene)
    nodes, links = tree.nodes, tree.links
    group = nodes[GROUP]
    wires = [("albedo", "Image", "Albedo"), ("albedo", "Depth", "Albedo Depth"), ("shading", "Image", "Shading"),
             ("residual", "Image", "Residual"), ("scene", "Image", "Scene")]
    if previewing:
        wires += [("edit", "Image", "Edit"), ("edit", "Depth", "Edit Depth")]
    if lighting:
        wires.append(("lit", "Image", "Lit"))
    if occluding:
        wires += [("occluded", "Image", "Occluded"), ("open", "Image", "Open")]
    if occluding and captured_lights.shadows_on():
        wires += [("direct", "Image", "Direct"), ("direct_open", "Image", "Direct Open")]
    wanted = {(VIEW_LAYERS[role], out, into) for role, out, into in wires}
    for link in list(group.inputs[i] for i in range(len(group.inputs))):
        for lk in list(link.links):
            if (lk.from_node.name, lk.from_socket.name, link.name) not in wanted:
                links.remove(lk)
    for layer, out, into in wanted:
        src = nodes[layer].outputs.get(out)
        if src is not None and not group.inputs[into].is_linked:
            links.new(src, group.inputs[into])
    chosen = OUTPUTS.get(scene.igs.render_layer, "Image")
    target = nodes["IGS Output"].inputs[0]
    if not (target.is_linked and target.links[0].from_socket.name == chosen and target.links[0].from_node == group):
        for lk in list(target.links):
            links.remove(lk)
        links.new(group.outputs[chosen], target)


# -- the scene ----------------------------------------------------------------------------------------------------


def gather_loose(scene: bpy.types.Scene) -> str:
    """Move the objects lying directly in the Scene Collection into :data:`SCENE_OBJECTS` (each view layer can
    then hold them out or leave them out); returns what it did, for the report."""
    loose = loose_objects(scene)
    if not loose:
        return ""
    coll = bpy.data.collections.get(SCENE_OBJECTS) or bpy.data.collections.new(SCENE_OBJECTS)
    if coll.name not in scene.collection.children:
        scene.collection.children.link(coll)
    for obj in loose:
        if obj.name not in coll.objects:
            coll.objects.link(obj)
        scene.collection.objects.unlink(obj)
    return f"moved {len(loose)} object(s) from the Scene Collection into '{SCENE_OBJECTS}'"


def setup(scene: bpy.types.Scene) -> list[str]:
    """Make ``scene``'s render the composite (module docstring); returns what it changed, for the report."""
    notes = [gather_loose(scene)] if loose_objects(scene) else []
    for vl in scene.view_layers:
        if vl.name not in VIEW_LAYERS.values() and vl.use:
            vl["igs_use_before"] = True
            vl.use = False
            notes.append(f"view layer '{vl.name}' no longer renders (the IGS view layers do)")
    for role, name in VIEW_LAYERS.items():
        vl = scene.view_layers.get(name) or scene.view_layers.new(name)
        vl.use_pass_combined = True
        vl.use_pass_z = role in ("albedo", "edit")
    notes += native_lighting.update(scene)
    note = captured_lights.update(scene, native_lighting.NORMAL)
    notes += [note] if note else []
    r = scene.render
    r.film_transparent = True
    r.use_single_layer = False
    if scene.view_settings.view_transform != "Standard":
        notes.append(f"view transform {scene.view_settings.view_transform} -> Standard (the sRGB of igs render)")
        scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    sync(scene)
    return notes


def sync(scene: bpy.types.Scene) -> None:
    """Bring the view layers, the objects' render visibility and the compositor up to date with the scene:
    new collections, the edit the render uses, the proxy being previewed, Render > Layer."""
    if not is_set_up(scene):
        return
    props = scene.igs
    own = _own_collections(scene)
    proxy = preview_proxy(props)
    for role, name in VIEW_LAYERS.items():
        vl = scene.view_layers.get(name)
        if vl is None:
            vl = scene.view_layers.new(name)
            vl.use_pass_z = role in ("albedo", "edit")
        _apply(vl.layer_collection, role, own)
        if role == "edit":
            if proxy is not None:
                vl.material_override = _override_material(proxy)
            vl.use = proxy is not None
    _gather_proxies(props)
    _albedo_visibility(props, proxy)
    native_lighting.update(scene)
    captured_lights.update(scene, native_lighting.NORMAL)
    sync_lighting(scene)
    _wire(scene, proxy is not None, lighting(scene), _occluding(scene))


def _occluding(scene: bpy.types.Scene) -> bool:
    return native_lighting.occluders(scene, set(_own_collections(scene)) | set(VIEW_LAYERS.values()))


def lighting(scene: bpy.types.Scene) -> bool:
    """Blender lights the capture (the view layer "IGS Lit" renders): the lights collection holds a visible
    light and the shading layer shows no backend bake (``light-bake``'s lights are in it already)."""
    shading = layers.loaded_layers().get("shading")
    baked = shading is not None and bool(shading.get("igs_lights"))  # light_bake.KEY
    return native_lighting.lights_on(scene) and not baked


def sync_lighting(scene: bpy.types.Scene) -> None:
    """The lights' part of :func:`sync`, cheap enough for every depsgraph update that touches a light: the lit
    view layer on or off, the other lights kept off the capture, the normals' matrix, the wiring."""
    vl = scene.view_layers.get(VIEW_LAYERS["lit"])
    if vl is None:
        return
    on = lighting(scene)
    occluding = _occluding(scene)
    lamps = occluding and captured_lights.shadows_on()
    rewire = vl.use != on or _wired(scene, "Lit") != on or _wired(scene, "Open") != occluding \
        or _wired(scene, "Direct Open") != lamps
    if vl.use != on:
        vl.use = on
    world = native_lighting.dark_world()
    direct = captured_lights.direct_material()
    for role in ("occluded", "open", "direct", "direct_open"):
        layer = scene.view_layers.get(VIEW_LAYERS[role])
        if layer is None:
            continue
        use = occluding if role in ("occluded", "open") else lamps
        if layer.use != use:
            layer.use = use
        mat = native_lighting.occlusion_material() if role in ("occluded", "open") else direct
        if layer.material_override != mat:
            layer.material_override = mat
        if role in ("direct", "direct_open") and layer.world_override != world:  # only the lamps light there
            layer.world_override = world
    mat = native_lighting.lit_material()
    if vl.material_override != mat:
        vl.material_override = mat
    if vl.world_override != world:
        vl.world_override = world
    albedos = native_lighting.albedo_objects()
    if albedos:
        for material in (mat, native_lighting.occlusion_material(), direct):
            native_lighting.set_normal_matrix(material, native_lighting.normal_matrix())
        native_lighting.exclude_other_lights(scene, albedos)
    if rewire:  # only on a change: this runs on depsgraph updates, and every write triggers another
        _wire(scene, preview_proxy(scene.igs) is not None, on, occluding)


def _wired(scene: bpy.types.Scene, into: str) -> bool:
    tree = bpy.data.node_groups.get(TREE)
    group = tree.nodes.get(GROUP) if tree is not None else None
    socket = group.inputs.get(into) if group is not None else None
    return socket is not None and socket.is_linked


HOME = "igs_home_collections"
"""Custom property of an artist's mesh made a proxy: the collections it lived in (:func:`send_home`)."""


def _gather_proxies(props) -> None:
    """Every edit's proxy in "IGS Edits": a mesh the artist made a proxy (Use Selection as Proxy) is an edit of
    the albedo now, not a scene object to render lit and to hold the fields out with."""
    coll = scene_objects.collection(proxies.COLLECTION)
    for item in props.edits:
        obj = item.proxy
        if obj is None or obj.name in coll.objects:
            continue
        homes = [c for c in obj.users_collection if c != coll]
        obj[HOME] = json.dumps([c.name for c in homes])
        coll.objects.link(obj)
        for c in homes:
            c.objects.unlink(obj)


def send_home(obj: bpy.types.Object, scene: bpy.types.Scene) -> None:
    """An artist's mesh that is no longer a proxy goes back to the collections it came from."""
    if HOME not in obj:
        return
    for name in json.loads(obj[HOME]):
        coll = bpy.data.collections.get(name) or (scene.collection if name == scene.collection.name else None)
        if coll is not None and obj.name not in coll.objects:
            coll.objects.link(obj)
    for c in list(obj.users_collection):
        if c.name == proxies.COLLECTION and len(obj.users_collection) > 1:
            c.objects.unlink(obj)
    del obj[HOME]


def _albedo_visibility(props, proxy) -> None:
    """The albedo field renders the workspace albedo, or the render edit's baked albedo instead; only the
    previewed proxy renders in the edit layer."""
    item = render_edit(props)
    baked = item.albedo if item is not None and item.albedo is not None else None
    original = layers.loaded_layers().get("albedo")
    if original is not None:
        original.hide_render = baked is not None
    for other in props.edits:
        if other.albedo is not None:
            other.albedo.hide_render = other.albedo != baked
        if other.proxy is not None and "igs_edit" in other.proxy:
            other.proxy.hide_render = other.proxy != proxy


def teardown(scene: bpy.types.Scene) -> None:
    """Undo :func:`setup`: the IGS view layers and the effect go, the other view layers render again."""
    for name in VIEW_LAYERS.values():
        vl = scene.view_layers.get(name)
        if vl is not None and len(scene.view_layers) > 1:
            scene.view_layers.remove(vl)
    for vl in scene.view_layers:
        if vl.get("igs_use_before"):
            vl.use = True
            del vl["igs_use_before"]
    compat.remove_compositor_tree(scene, TREE)
    native_lighting.release(scene)
    captured_lights.release()


_SIGNATURE: dict[str, tuple] = {}


def _signature(scene) -> tuple:
    return tuple(c.name for c in scene.collection.children_recursive)


@bpy.app.handlers.persistent
def _on_depsgraph(scene, depsgraph=None) -> None:
    """A collection added after the setup gets its flags in the IGS view layers (a cheap check per update); a
    light added, moved or hidden turns the lit view layer on or off and keeps the other lights off the capture."""
    if not is_set_up(scene) or not hasattr(scene, "igs"):
        return
    if depsgraph is None or any(isinstance(u.id, (bpy.types.Object, bpy.types.Light, bpy.types.Collection))
                                for u in depsgraph.updates):
        try:
            sync_lighting(scene)
        except ReferenceError:  # a scene being torn down; the next update looks again
            pass
    sig = _signature(scene)
    if _SIGNATURE.get(scene.name) != sig:
        _SIGNATURE[scene.name] = sig
        own = _own_collections(scene)
        for role, name in VIEW_LAYERS.items():
            vl = scene.view_layers.get(name)
            if vl is not None:
                _apply(vl.layer_collection, role, own)


def register() -> None:
    add_depsgraph_handler(_on_depsgraph)


def unregister() -> None:
    remove_depsgraph_handler(_on_depsgraph)
    _SIGNATURE.clear()
