"""edit: albedo edits through proxies (paper section 3.4).

proxy (the proxy.json format, plane/cylinder builders), ransac (robust plane/cylinder fits),
fit (proxies from a rectangle of max-contributor ids), surface_points (depth-prior points the fits grow on),
sweep (a fitted surface moved to where the field shows its texture), texture (a view projected onto a
proxy's UVs), mesh_raster (textured triangle rasteriser), composite (proxy over the albedo render, depth
test), views (rectangle validation, visibility check, hemisphere views), workspace_edits (the edit folders
and the albedo layer an edit starts from), albedo_render (the albedo field rendered, alone or edited),
view_selection (the edit view and the capture views that see the proxy).

The bake: bake (:func:`bake.bake_edit`, phase by phase) with bake_config (its settings), spawn (the new
flat Gaussians), touched_gaussians (the old ones on the proxy or under the edit), crop_windows (the
windows around the edit), bake_stage (the re-optimisation stage) and change_metrics (the change inside
and outside the edit).
"""
