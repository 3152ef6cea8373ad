"""Adding lights to a decomposed capture: I' = A * (S + S_new) + R (docs/relighting.md).

``lights`` reads the lights file, ``geometry`` gives each pixel its world point and normal,
``shadow_maps`` the visibility from a light (depth maps of a Gaussian field rendered at the light),
``irradiance`` the direct diffuse shading S_new = E * V / pi in Cycles' units, and ``relight`` puts
them together for a view.
"""
