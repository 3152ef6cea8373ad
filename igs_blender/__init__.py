"""The add-on core, run by Blender's own Python (bpy + numpy, never torch or the backend).

Its wings, from the ground up (docs/structure.md draws them): ``jobs`` (the backend process, the current
job and its command lines; no bpy), ``env`` (the backend's environment, its checks and the CUDA build;
no bpy), the scene modules at this level (layers' names and files, edits, proxies, lights, cameras,
scene objects, PLY files, compat, preferences), ``native`` (Blender 5.3's splats and render) beside
``viewport`` (our own engine and the point clouds), ``display`` (the one face that picks between
them), then the scene modules that use it (``edit_objects``, ``light_bake``, ``scene_renders``,
``splat_files``, ``props``). The extension's root module registers them with the operators and panels.
"""
