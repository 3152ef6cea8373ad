"""Our own splat engine in the 3D view: the draw handler (``overlay``), the GPU engine and its shaders, the
packing of layers into textures, the depth sort, the pinhole camera and the agreement with ``igs render``."""
