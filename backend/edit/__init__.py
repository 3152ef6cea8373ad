"""edit: albedo edits through proxies (paper section 3.4).

proxy (the proxy.json format, plane/cylinder builders), ransac (robust plane/cylinder fits),
fit (proxies from a rectangle of max-contributor ids), texture (a view projected onto a proxy's UVs),
mesh_raster (textured triangle rasteriser), composite (proxy over the albedo render, depth test),
views (rectangle validation, visibility check, hemisphere views, spawned Gaussians).
"""
