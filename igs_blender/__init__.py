"""The add-on core, run by Blender's own Python (bpy + numpy, never torch or the backend).

Modules: ``client`` and ``jobs`` (the backend subprocess and its JSON-lines events, no bpy),
``backend_env`` (interpreter, shipped sources, pinned requirements), ``ply_io`` (splat PLYs with
numpy), ``cameras`` (the workspace's cameras <-> Blender camera maths), ``layers`` / ``proxies`` /
``camera_objects`` / ``edits`` / ``scene_objects`` (the scene side), ``compat`` (everything that
differs between Blender versions), ``preferences`` and ``props`` (settings), ``addon_id`` (the
add-on's id). The extension's root module registers them with the operators and panels.
"""
