"""Intrinsic Splats — the Blender extension (manifest: blender_manifest.toml).

Decompose a capture into albedo, shading and residual Gaussians with the PyTorch backend, which
runs as a separate process (``python -m backend``), repaint surfaces with textured proxies placed
with Blender's gizmos, and render the edited scene. Blender's Python never imports the backend.

This module registers the add-on; ``igs_blender`` holds its core, ``operators`` and ``panels``
its UI (they import ``igs_blender``, never the other way round), ``igs_contract`` what it shares
with the backend. The UI modules import bpy, so they are imported when Blender registers the add-on.
"""


def classes() -> tuple:
    """Every class to register, in order (property groups before users, parent panels before children)."""
    from . import operators, panels
    from .igs_blender import preferences, props

    return (*props.CLASSES, *preferences.CLASSES, *operators.CLASSES, *panels.CLASSES)


def _on_load_pre(*_args) -> None:
    # A new file drops the modal operator that follows the job: stop the job cleanly (it keeps
    # its checkpoint) rather than leave an unwatched process behind.
    from .igs_blender import jobs, light_bake
    from .igs_blender.viewport import overlay

    jobs.request_cancel()
    overlay.VIEW.free()  # the GPU layers belong to the scene being closed
    light_bake.LIVE.reset()


def register() -> None:
    import atexit

    import bpy

    from .igs_blender import display, jobs, light_bake, props
    from .igs_blender.native import compositing
    from .igs_blender.viewport import overlay

    atexit.unregister(jobs.stop_all)  # Blender quitting: do not leave a backend process behind
    atexit.register(jobs.stop_all)

    for cls in classes():
        if not getattr(cls, "is_registered", False):
            bpy.utils.register_class(cls)
    props.register_pointer()
    overlay.register(display.viewport_engine_draws)
    compositing.register()
    light_bake.register()
    if _on_load_pre not in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.append(_on_load_pre)


def unregister() -> None:
    import atexit

    import bpy

    from .igs_blender import jobs, light_bake, props
    from .igs_blender.native import compositing
    from .igs_blender.viewport import overlay

    jobs.stop_all()
    light_bake.unregister()
    compositing.unregister()
    overlay.unregister()
    atexit.unregister(jobs.stop_all)
    if _on_load_pre in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.remove(_on_load_pre)
    props.unregister_pointer()
    for cls in reversed(classes()):
        if getattr(cls, "is_registered", False):
            bpy.utils.unregister_class(cls)
