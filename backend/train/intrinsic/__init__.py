"""The intrinsic decomposition (paper 3.2): albedo, shading and residual fields, trained in order.

Three separate Gaussian sets composited per pixel as ``I = A * S + R`` in (pseudo-)linear RGB:

1. **albedo** G_A: 3DGS on the albedo maps (inverse gamma, sigmoid colours), loss
   ``(1-λ) L1 + λ D-SSIM + λ_d depth L1 + λ_s mean scale``, densification and floater removal;
2. **shading** G_S: G_A frozen and rendered *once* per view into a cache; starts on a subset of G_A's
   Gaussians (or the SfM points), raw RGB gray at the image / albedo luminance ratio; diffuse model
   ``I = A * S`` with the photometric loss on ``1 / (1 + x)`` of both sides, the gray regulariser ``max(c) - min(c)``, depth
   and scale terms;
3. **residual** G_R: G_A and G_S frozen and cached as ``A * S`` per view; G_R spawned at the pixels
   where ``|I - A * S|`` is largest, placed with the depth prior; SH up to degree 3 with progressive
   bands; full model ``I = A * S + R``, only G_R updated.

Each stage is a :class:`backend.train.loop.Stage`, so checkpoints, resume, cancel and progress are
those of the shared loop. Between stages the finished layer is written to ``<ws>/layers/<kind>.ply``
and recorded in ``<ws>/checkpoints/decompose/state.json`` with the hash of the layers it was trained
on, so a rerun skips finished stages and redoes a stage whose inputs changed.

Modules: :mod:`.config` (settings), :mod:`.setup` (capture and split), :mod:`.initial` (starting
Gaussians), :mod:`.stages` (shading and residual stages), :mod:`.composite` (``A * S + R``),
:mod:`.state` (state.json), :mod:`.outcome` (summaries, capture.json) and :mod:`.run` (the stages in
order). The held-out evaluation, report.png and metrics.json belong to the eval room (decomposition.py).
"""
