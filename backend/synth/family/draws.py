"""The seeded draws a family layout is made from: numbers, colours from the palettes, surface
finishes, and free places on the floor (:class:`Floor`)."""

from __future__ import annotations

import numpy as np

from backend.synth.family.parts import CLEARANCE, EYE_RADIUS, Finish, Rect

# Linear RGB palettes.
SATURATED = {"red": (0.70, 0.03, 0.02), "green": (0.04, 0.45, 0.06), "blue": (0.02, 0.07, 0.60),
             "yellow": (0.75, 0.55, 0.02), "magenta": (0.55, 0.03, 0.40), "orange": (0.80, 0.22, 0.01),
             "cyan": (0.02, 0.45, 0.55)}
METALS = {"gold": (0.95, 0.72, 0.32), "copper": (0.93, 0.56, 0.43), "steel": (0.62, 0.63, 0.66),
          "brass": (0.85, 0.70, 0.40)}
MUTED_WALLS = [(0.55, 0.52, 0.45), (0.45, 0.50, 0.55), (0.60, 0.50, 0.42), (0.48, 0.55, 0.46),
               (0.62, 0.60, 0.58)]
SATURATED_WALLS = [(0.50, 0.06, 0.05), (0.05, 0.30, 0.35), (0.08, 0.12, 0.45), (0.55, 0.38, 0.03)]
LIGHT_RECOLORS = [(0.70, 0.70, 0.70), (0.72, 0.62, 0.50), (0.55, 0.66, 0.72), (0.70, 0.56, 0.62),
                  (0.60, 0.70, 0.52)]
SKIES = {  # (ground, horizon, zenith), linear
    "clear": ((0.16, 0.13, 0.10), (0.75, 0.80, 0.85), (0.20, 0.38, 0.80)),
    "hazy": ((0.22, 0.21, 0.19), (0.80, 0.80, 0.78), (0.50, 0.56, 0.66)),
    "dusk": ((0.12, 0.09, 0.09), (0.95, 0.58, 0.35), (0.25, 0.22, 0.45)),
}


def u(rng: np.random.Generator, lo: float, hi: float) -> float:
    """A uniform draw from [lo, hi)."""
    return float(rng.uniform(lo, hi))


def pick(rng: np.random.Generator, options: list | tuple):
    """One of ``options``, each as likely."""
    return options[int(rng.integers(len(options)))]


def vary(rng: np.random.Generator, rgb, amount: float = 0.1) -> tuple[float, float, float]:
    """``rgb`` scaled per channel by 1 +- ``amount`` (saturated colours stay saturated)."""
    return tuple(float(np.clip(c * (1 + rng.uniform(-amount, amount)), 0.0, 0.95)) for c in rgb)


def near_black(rng: np.random.Generator) -> tuple[float, float, float]:
    """A linear albedo of 0.01-0.04 with a slight tint."""
    g = u(rng, 0.012, 0.035)
    return tuple(float(g * (1 + rng.uniform(-0.15, 0.15))) for _ in range(3))


class Floor:
    """Where floor pieces may go: inside the walls, clear of the camera's eye ellipse (or inside it, for
    the central piece), of keep-out rectangles and of each other."""

    def __init__(self, hx: float, hy: float):
        self.hx, self.hy = hx, hy
        self.keep_out: list[tuple[Rect, float]] = []

    def inside_room(self, r: Rect, margin: float) -> bool:
        return r.x0 > -self.hx + margin and r.x1 < self.hx - margin and r.y0 > -self.hy + margin \
            and r.y1 < self.hy - margin

    def ellipse(self, r: Rect, grow: float) -> np.ndarray:
        """(x/a)^2 + (y/b)^2 of the rectangle's outline for the eye ellipse grown by ``grow`` metres."""
        p = r.outline()
        a, b = EYE_RADIUS * self.hx + grow, EYE_RADIUS * self.hy + grow
        return (p[:, 0] / a) ** 2 + (p[:, 1] / b) ** 2

    def free(self, r: Rect, central: bool) -> bool:
        if not self.inside_room(r, 0.05):
            return False
        if central and not (self.ellipse(r, -CLEARANCE) < 1).all():
            return False
        if not central and not (self.ellipse(r, CLEARANCE) > 1).all():
            return False
        return not any(r.overlaps(k, m) for k, m in self.keep_out)

    def place(self, rng: np.random.Generator, size: tuple[float, float], central: bool,
              tries: int = 600) -> Rect | None:
        """A free spot for a ``size`` footprint (x, y metres), drawn uniformly; None if none was found."""
        sx, sy = size
        for _ in range(tries):
            if central:
                cx = u(rng, -EYE_RADIUS * self.hx, EYE_RADIUS * self.hx) * 0.5
                cy = u(rng, -EYE_RADIUS * self.hy, EYE_RADIUS * self.hy) * 0.5
            else:
                cx = u(rng, -self.hx + sx / 2, self.hx - sx / 2)
                cy = u(rng, -self.hy + sy / 2, self.hy - sy / 2)
            r = Rect.around(cx, cy, sx, sy)
            if self.free(r, central):
                return r
        return None


def saturated(rng: np.random.Generator) -> tuple[float, float, float]:
    return vary(rng, SATURATED[pick(rng, list(SATURATED))], 0.08)


def metal_finish(rng: np.random.Generator) -> Finish:
    return Finish("metal", METALS[pick(rng, list(METALS))], roughness=u(rng, 0.08, 0.3))


def glossy_finish(rng: np.random.Generator) -> Finish:
    """A glossy dielectric: diffuse + GGX lobe, or a Principled plastic."""
    if rng.random() < 0.5:
        return Finish("glossy", saturated(rng), roughness=u(rng, 0.05, 0.2), gloss=u(rng, 0.4, 0.7))
    return Finish("plastic", saturated(rng), roughness=u(rng, 0.15, 0.4))
