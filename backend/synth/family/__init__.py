"""A procedural family of synthetic scenes: ``igs synth --scene-seed K`` builds scene K.

Every default of the project was first tuned on the one room of :mod:`room`; tuning on a few
family scenes instead cannot memorise one layout. Scene K varies, from K alone:

- the room: its size, which wall is open to the world (fully, or above a low parapet), an optional
  skylight (a hole in the ceiling), the floor (wood or tiles), which wall is wallpapered, wall colours
  (sometimes one saturated wall), the world's gradient (clear, hazy or dusk);
- the wall pieces: a framed picture (a hard-edged canvas inside a raised frame of gilt metal, black
  lacquer or varnished wood) and a near-black panel, each on its own wall, at seeded places and sizes,
  and a poster of saturated, high-frequency, many-coloured content (a procedural photograph, a
  patchwork of patterns or typography: :mod:`backend.synth.pictures`), flat or in a thin frame, on a
  free spot of a closed wall (:mod:`~backend.synth.family.poster`);
- the floor: a rug with hard borders, a textured decal region crossed by the sun's shadow edge, a
  table or a painted block in the middle with two or three things on it, and a column, a plinth with
  a metal vase or torus and one or two more pieces (a black cabinet, a glossy floor vase, a second
  plinth, a metal pillar) along the walls;
- the lights: a sun through the open side (its azimuth and elevation set so that the shadow of the
  opening's top edge crosses the decal), the world, one or two area lights, a point light in front of
  the dark panel, sometimes a coloured accent point light and a hard spot light.

Every scene has near-black albedos (the panel at 0.01-0.04 linear, sometimes a black cabinet, plinth
or frame) and saturated ones (objects, rug, canvas), glossy (diffuse + GGX), Principled plastic and
metallic surfaces (a metal's Diffuse Color is 0: it lives in the residual), spheres, cylinders, a
torus or vase, and hard shadows across textured surfaces.

The four edits (``gt_edit/<edit>``, all on planes, so :class:`PlaneSurface`):

- ``canvas_recolor``: the picture's whole canvas, exactly to its border, to a flat light colour;
- ``dark_recolor``: the whole near-black panel to a light grey or pastel (the shading where the
  albedo was dark is then in plain view);
- ``decal``: a texture on the floor, crossed by the sun's hard shadow edge;
- ``poster_recolor``: the whole poster, exactly to its border, to a flat colour (light, or a saturated
  red or blue): a shading that kept the poster's texture shows it as a ghost in the repaint.

:func:`~backend.synth.family.layout.family_layout` draws the layout (pure numpy; the camera path
needs only it): what a layout is made of is :mod:`~backend.synth.family.parts`, the seeded draws of
numbers, colours and finishes :mod:`~backend.synth.family.draws`, the floor pieces
:mod:`~backend.synth.family.pieces`, the lights :mod:`~backend.synth.family.lamps` and the poster
:mod:`~backend.synth.family.poster` (drawn last, from streams of its own).
:func:`~backend.synth.family.build.build_family_scene` builds it in bpy. Textures come from a second
random stream, in a fixed order, through :mod:`backend.synth.textures` (which the Blender-binary
worker forwards to the backend).
"""
