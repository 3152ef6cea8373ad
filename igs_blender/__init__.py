"""The add-on core, run by Blender's own Python (bpy + numpy, never torch or the backend).

Modules: ``client`` and ``jobs`` (the backend subprocess and its JSON-lines events, no bpy),
``backend_env`` (interpreter, shipped sources, pinned requirements), ``ply_io`` (splat PLYs with
numpy), ``cameras`` (COLMAP <-> Blender camera maths), ``layers`` / ``proxies`` /
``camera_objects`` / ``edits`` / ``scene_objects`` (the scene side), ``compat`` (everything that
differs between Blender versions), ``preferences`` and ``props`` (settings).
"""

# The extension's package ("bl_ext.<repo>.intrinsic_splats"): the add-on preferences' bl_idname.
ADDON_ID = __package__.rpartition(".")[0] or __package__


def classes() -> tuple:
    """Every class to register, in order (property groups before users, parent panels before children)."""
    from .. import operators, panels
    from . import preferences, props

    return (*props.CLASSES, *preferences.CLASSES, *operators.CLASSES, *panels.CLASSES)


def _on_load_pre(*_args) -> None:
    # A new file drops the modal operator that follows the job: stop the job cleanly (it keeps
    # its checkpoint) rather than leave an unwatched process behind.
    from . import jobs

    jobs.request_cancel()


def register() -> None:
    import atexit

    import bpy

    from . import jobs, props

    atexit.unregister(jobs.stop_all)  # Blender quitting: do not leave a backend process behind
    atexit.register(jobs.stop_all)

    for cls in classes():
        if not getattr(cls, "is_registered", False):
            bpy.utils.register_class(cls)
    props.register_pointer()
    if _on_load_pre not in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.append(_on_load_pre)


def unregister() -> None:
    import atexit

    import bpy

    from . import jobs, props

    jobs.stop_all()
    atexit.unregister(jobs.stop_all)
    if _on_load_pre in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.remove(_on_load_pre)
    props.unregister_pointer()
    for cls in reversed(classes()):
        if getattr(cls, "is_registered", False):
            bpy.utils.unregister_class(cls)
