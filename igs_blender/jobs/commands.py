"""The backend's command lines, one builder per command, from the option names the CLI uses (no bpy).

An option is given by its CLI name with ``_`` for ``-`` (``max_frames=3`` is ``--max-frames 3``); a
value of True is a bare flag, None, False or "" leaves the option out, and a tuple gives one word per
item (``rect=(x0, y0, x1, y1)``). Zero is a value: a builder leaves out what the panel's 0 means "the
backend's default" itself.
"""

from __future__ import annotations

from pathlib import Path

Word = str | int | float | Path


def command_line(words: tuple, options: dict) -> list[Word]:
    """``words`` (the command and its positionals), then each option as the CLI spells it, in the given order."""
    out: list[Word] = list(words)
    for name, value in options.items():
        if value is None or value is False or value == "":
            continue
        flag = "--" + name.replace("_", "-")
        if value is True:
            out.append(flag)
        elif isinstance(value, tuple):
            out += [flag, *value]
        else:
            out += [flag, value]
    return out


def synth(ws: Path, *, preset: str, seed: int, scene_seed: int | None = None, blender: str | None = None,
          force: bool = False) -> list[Word]:
    return command_line(("synth", ws), {"preset": preset, "seed": seed, "scene_seed": scene_seed,
                                        "blender": blender, "force": force})


def import_capture(src: Path, ws: Path, *, kind: str, force: bool = False, every: int | None = None,
                   max_frames: int = 0, max_side: int = 0, albedo: str | None = None,
                   depth: str | None = None) -> list[Word]:
    """``igs import``; ``max_frames`` and ``max_side`` 0: no limit."""
    return command_line(("import", src, ws), {"kind": kind, "force": force, "every": every,
                                              "max_frames": max_frames or None, "max_side": max_side or None,
                                              "albedo": albedo, "depth": depth})


def decompose(ws: Path, *, stage: str | None = None, iterations: int = 0, restart: bool = False) -> list[Word]:
    """``igs decompose``; ``iterations`` 0: the stage's default."""
    return command_line(("decompose", ws), {"stage": stage, "iterations": iterations or None, "restart": restart})


def native_tune(ws: Path, *, iterations: int = 0) -> list[Word]:
    """``igs native-tune``; ``iterations`` 0: the backend's default."""
    return command_line(("native-tune", ws), {"iterations": iterations or None})


def train_3dgs(ws: Path, *, iterations: int = 0, restart: bool = False) -> list[Word]:
    return command_line(("train-3dgs", ws), {"iterations": iterations or None, "restart": restart})


def fit(primitive: str, ws: Path, *, view: str, rect: tuple, name: str, out: Path, threshold: float = 0.0,
        min_selected: int | None = None) -> list[Word]:
    """``igs edit fit-<primitive>``; ``threshold`` 0: the backend's own."""
    # float32 settings: 0.05, not 0.0500000007
    return command_line(("edit", f"fit-{primitive}", ws), {
        "view": view, "rect": tuple(rect), "name": name, "out": out,
        "threshold": f"{threshold:.6g}" if threshold > 0 else None, "min_selected": min_selected})


def bake(ws: Path, *, proxy: Path, name: str, iterations: int = 0) -> list[Word]:
    return command_line(("edit", "bake", ws), {"proxy": proxy, "name": name, "iterations": iterations or None})


def project(ws: Path, *, proxy: Path, out: Path) -> list[Word]:
    return command_line(("edit", "project", ws), {"proxy": proxy, "out": out})


def convert(path: Path, out: Path, *, kind: str | None = None, space: str | None = None) -> list[Word]:
    return command_line(("convert", path, out), {"kind": kind, "space": space})


def export(ws: Path, *, layer: str, format: str, out: Path, edit: str = "") -> list[Word]:
    return command_line(("export", ws), {"layer": layer, "format": format, "edit": edit, "out": out})


def distil(ws: Path, *, out: Path, edit: str = "", iterations: int = 0) -> list[Word]:
    return command_line(("distil", ws), {"edit": edit, "out": out, "iterations": iterations or None})


def render(ws: Path, *, out: Path, layers: str, edit: str = "", light: Path | None = None,
           cameras: Path | None = None, turntable: tuple | None = None, mp4: bool = False) -> list[Word]:
    """``igs render`` from a cameras file Blender wrote, or the backend's own turntable of the capture:
    ``turntable=(frames, width, height)``."""
    frames, size = (turntable[0], tuple(turntable[1:])) if turntable else (None, None)
    return command_line(("render", ws), {"edit": edit, "light": light, "cameras": cameras,
                                         "turntable": turntable is not None, "frames": frames, "size": size,
                                         "out": out, "layers": layers, "mp4": mp4})


def light_bake(ws: Path, *, light: Path) -> list[Word]:
    return command_line(("light-bake", ws), {"light": light})
