"""The add-on's id: the extension's package ("bl_ext.<repo>.intrinsic_splats"), the preferences' bl_idname."""

# This module is <extension>.igs_blender.addon_id: the extension's package is its package's parent.
ADDON_ID = __package__.rpartition(".")[0] or __package__
