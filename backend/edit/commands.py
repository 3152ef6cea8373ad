"""``igs edit``: fit a proxy to a rectangle of a view, project the albedo onto it, bake it into G_A.

- ``igs edit fit-plane <ws> --view NAME --rect x0 y0 x1 y1 [--name N]`` and ``fit-cylinder`` write
  ``<ws>/edits/<N>/proxy.json`` (format: :mod:`backend.edit.proxy`), its texture ``proxy.png`` (the
  rendered albedo projected onto the proxy's UVs, the starting image for painting; ``--color`` gives a
  flat colour instead) and ``edit.json`` (edit view, rectangle, the fitted surface in world space).
- ``igs edit project <ws> --proxy P [--view NAME] [--out Q]``: the current albedo field projected onto
  the proxy's UVs as seen from a view (Blender's "Paint" starting image), written as a new proxy
  file ``Q`` (default ``<proxy dir>/projected.json``) with its texture beside it.
- ``igs edit bake <ws> (--proxy P | --plane plane.json (--texture IMG | --color r,g,b)) [--name N]``:
  :func:`backend.edit.bake.bake_edit`.

``plane.json`` (the convenience form of ``--plane``): ``{"center": [3], "normal": [3], "u_axis": [3],
"v_axis": [3], "size": [w, h]}`` in world units (the ``"plane"`` entry of a fit's edit.json, or the
``"surface"`` of a synthetic ``gt_edit/<edit>/edit.json``); UV (0, 0) at ``center - w/2 u - h/2 v``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from backend import options as opt
from backend.capture.load import load_capture
from backend.core import events
from backend.core.atomic_io import write_json
from backend.core.errors import IGSError
from backend.core.imageio import read_linear
from backend.core.paths import plain_name
from backend.edit.bake import (
    EDIT_JSON,
    BakeConfig,
    bake_edit,
    edit_dir,
    load_albedo,
    render_albedo,
    resolve_view,
)
from backend.edit.fit import FitConfig, fit_cylinder_from_rect, fit_plane_from_rect
from backend.edit.proxy import ProxyMesh, load_proxy, plane_proxy, save_proxy
from backend.edit.surface_points import GROW_ON, fit_grown
from backend.edit.sweep import sweep_fitted
from backend.edit.texture import textured_from_view
from backend.train.device import add_device_argument
from backend.train.views import view_camera

BACKENDS = ("auto", "cpu", "reference", "gsplat")


def parse_color(text: str, what: str = "--color") -> np.ndarray:
    """'r,g,b' linear RGB in [0, 1] -> (3,) float32."""
    try:
        c = np.array([float(v) for v in str(text).split(",")], dtype=np.float32)
    except ValueError:
        c = np.zeros(0)
    if c.shape != (3,) or not np.isfinite(c).all() or (c < 0).any() or (c > 1).any():
        raise IGSError(f"{what} must be three linear RGB values in [0, 1] as r,g,b, got {text!r}")
    return c


def _vec(d: dict, key: str, n: int, where: str) -> np.ndarray:
    try:
        v = np.asarray(d[key], dtype=np.float64).reshape(n)
    except KeyError:
        raise IGSError(f"{where}: missing '{key}'") from None
    except (TypeError, ValueError):
        raise IGSError(f"{where}: '{key}' must be {n} numbers") from None
    if not np.isfinite(v).all():
        raise IGSError(f"{where}: '{key}' has NaN or infinite values")
    return v


def plane_from_json(path: str | Path, texture: str | None, color: str | None, name: str) -> ProxyMesh:
    """A plane proxy from a ``plane.json`` (module docstring) and a texture file or a flat colour."""
    path = Path(path)
    if (texture is None) == (color is None):
        raise IGSError("--plane needs exactly one of --texture IMG or --color r,g,b")
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise IGSError(f"{path}: plane file not found") from None
    except (OSError, json.JSONDecodeError) as e:
        raise IGSError(f"{path}: not a readable JSON file ({e})") from e
    if isinstance(data, dict) and isinstance(data.get("plane"), dict):
        data = data["plane"]
    elif isinstance(data, dict) and isinstance(data.get("surface"), dict):
        data = data["surface"]
    if not isinstance(data, dict):
        raise IGSError(f"{path}: expected a JSON object with center, normal, u_axis, v_axis, size")
    where = str(path)
    c, n, u, v = (_vec(data, k, 3, where) for k in ("center", "normal", "u_axis", "v_axis"))
    size = _vec(data, "size", 2, where)
    tex = None
    if texture is not None:
        tp = Path(texture)
        if not tp.is_file():
            raise IGSError(f"--texture {tp}: file not found")
        tex = read_linear(tp)[..., :3].astype(np.float32)
    proxy = plane_proxy(c, n, u, v, size, name=name, texture=tex,
                        color=None if color is None else parse_color(color))
    if texture is not None:
        proxy.texture_path = Path(texture).resolve()
    # plane_proxy may flip the normal to keep v: that is fine, the proxy is two-sided.
    return proxy


def world_plane(proxy: ProxyMesh) -> dict[str, Any]:
    """World-space centre, normal, in-plane axes and size of a plane proxy (rigid matrix_world)."""
    m = proxy.matrix_world
    x, y, z = (m[:3, i] for i in range(3))
    w, h = proxy.primitive["size"]
    sx, sy = np.linalg.norm(x), np.linalg.norm(y)
    return {"center": m[:3, 3].tolist(), "normal": (z / np.linalg.norm(z)).tolist(), "u_axis": (x / sx).tolist(),
            "v_axis": (y / sy).tolist(), "size": [float(w * sx), float(h * sy)]}


def world_cylinder(proxy: ProxyMesh) -> dict[str, Any]:
    m = proxy.matrix_world
    p = proxy.primitive
    return {"base": m[:3, 3].tolist(), "axis": (m[:3, 2] / np.linalg.norm(m[:3, 2])).tolist(),
            "x_dir": (m[:3, 0] / np.linalg.norm(m[:3, 0])).tolist(), "radius": p["radius"], "height": p["height"],
            "angle_range": p["angle_range"], "mirror_u": bool(p.get("mirror_u", False))}


# ----------------------------------------------------------------------------------------------
# Commands


def run_fit(args: argparse.Namespace, kind: str) -> dict[str, Any]:
    _check_names(args)
    capture = load_capture(args.workspace)
    ws = capture.workspace
    albedo, source = load_albedo(ws, args.base)
    cam = view_camera(capture.frame(args.view).camera, 1.0)
    out = render_albedo(albedo, cam, args.backend, return_ids=True)
    cfg = FitConfig(seed=args.seed, threshold=args.threshold, min_selected=args.min_selected,
                    grow=getattr(args, "grow", True))
    color = parse_color(args.color) if args.color else (0.5, 0.5, 0.5)
    fit_fn = fit_plane_from_rect if kind == "plane" else fit_cylinder_from_rect
    centres = albedo.means.detach()
    if cfg.grow:
        fit, grown_on = fit_grown(fit_fn, capture, getattr(args, "grow_on", "auto"), centres.numpy(),
                                  cam, out.ids, centres, args.rect, config=cfg, name=args.name, color=color)
    else:
        fit, grown_on = fit_fn(cam, out.ids, centres, args.rect, config=cfg, name=args.name, color=color), "not grown"
    proxy = fit.proxy
    sweep = None
    if getattr(args, "sweep", True):
        proxy, sweep = sweep_fitted(capture, albedo, proxy, cam, args.backend)
        moved = ("moved the plane by " if kind == "plane" else "changed the radius by ") + format(sweep.offset, "+.4g")
        events.log(f"fit-{kind}: offset sweep {moved if sweep.accepted else 'kept the ' + kind} ({sweep.reason})")
    if not args.color:  # the rendered albedo projected onto the proxy: painting starts from the scene
        proxy = textured_from_view(proxy, cam, out.color.clamp(0, 1).numpy())
    path = Path(args.out) if args.out else edit_dir(ws, args.name) / "proxy.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    save_proxy(path, proxy)
    surface = world_plane(proxy) if kind == "plane" else world_cylinder(proxy)
    meta = {"name": args.name, "edit_view": cam.name, "rect": [float(v) for v in args.rect],
            "rect_pixels": [fit.rect.x0, fit.rect.y0, fit.rect.x1, fit.rect.y1], "kind": kind, kind: surface,
            "selected_gaussians": len(fit.gaussian_ids), "inliers": int(np.sum(fit.fit.inliers)),
            "extent_source": fit.extent_source, "albedo": str(source), "proxy": str(path)}
    meta["grown_points"] = fit.grown_points
    meta["grown_on"] = grown_on
    if sweep is not None:
        meta["offset_sweep"] = {"offset": sweep.offset, "accepted": sweep.accepted, "reason": sweep.reason}
    if fit.ransac_fit is not None:
        if kind == "cylinder":
            meta["rectangle_fit_radius"] = fit.ransac_fit.radius
        else:
            cos = abs(float(np.dot(fit.ransac_fit.normal, fit.fit.normal)))
            meta["rectangle_fit_tilt_deg"] = float(np.degrees(np.arccos(min(1.0, cos))))
    write_json(path.parent / EDIT_JSON, meta)
    events.output("proxy", path)
    grown = f", refined on {fit.grown_points} points of the {grown_on.split(' (')[0]}" if fit.grown_points else ""
    events.log(f"fit-{kind}: {len(fit.gaussian_ids)} Gaussians selected, {meta['inliers']} inliers{grown}; "
               f"wrote {path}")
    events.result(f"edit fit-{kind}", meta)
    return meta


def run_project(args: argparse.Namespace) -> None:
    capture = load_capture(args.workspace)
    src = Path(args.proxy)
    proxy = load_proxy(src)
    albedo, _ = load_albedo(capture.workspace, args.base)
    cam = resolve_view(capture, proxy, src, BakeConfig(view=args.view))
    out = render_albedo(albedo, cam, args.backend)
    textured = textured_from_view(proxy, cam, out.color.clamp(0, 1).numpy(), args.texels_per_pixel)
    dst = Path(args.out) if args.out else src.parent / "projected.json"
    save_proxy(dst, textured)
    events.output("proxy", dst)
    events.log(f"project: albedo seen from {cam.name} projected onto '{proxy.name}'; wrote {dst}")


def _check_names(args: argparse.Namespace) -> None:
    """Edit names are folders under <ws>/edits: checked before any work."""
    for option in ("name", "base"):
        if getattr(args, option, None) is not None:
            plain_name(getattr(args, option), f"--{option}")


def run_bake(args: argparse.Namespace) -> None:
    _check_names(args)
    if (args.proxy is None) == (args.plane is None):
        raise IGSError("give exactly one of --proxy proxy.json or --plane plane.json")
    if args.proxy is not None and (args.texture or args.color):
        raise IGSError("--texture/--color go with --plane; a proxy file carries its own texture or colour")
    name = args.name
    if args.proxy is not None:
        proxy: Any = Path(args.proxy)
        if not proxy.is_file():
            raise IGSError(f"--proxy {proxy}: file not found")
        if name is None:
            name = proxy.parent.name if proxy.parent.parent.name == "edits" else proxy.stem
    else:
        name = name or Path(args.plane).stem
        proxy = plane_from_json(args.plane, args.texture, args.color, name)
    cfg = BakeConfig(view=args.view, views=args.views, max_angle=args.max_angle, spawn_fraction=args.spawn_fraction,
                     iterations=args.iterations, anchor_views=args.anchor_views, capture_views=args.capture_views,
                     restrict=not args.no_restrict,
                     base=args.base, downscale=args.downscale, backend=args.backend, device=args.device,
                     seed=args.seed, surface=args.surface, supersample=args.supersample,
                     edit_filter=args.edit_filter)
    summary = bake_edit(args.workspace, proxy, name, cfg)
    events.result("edit bake", {k: v for k, v in summary.items() if k not in ("config",)} | {
        "held_out": {k: v for k, v in summary["held_out"].items() if k != "views"}})


# ----------------------------------------------------------------------------------------------
# Parsers


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("workspace", help="workspace folder")
    p.add_argument("--base", default=None, help="edit the albedo of <ws>/edits/BASE (stacking) instead of <ws>/layers")
    p.add_argument("--backend", default="auto", choices=BACKENDS, help="renderer backend (default auto)")
    p.add_argument("--seed", type=opt.SEED, default=0, help="random seed (default 0)")


def _add_fit(sub, kind: str) -> None:
    p = sub.add_parser(
        f"fit-{kind}", help=f"fit a {kind} proxy to a rectangle of a view",
        description=f"RANSAC {kind} over the centres of the albedo Gaussians with the largest blending weight in "
        f"each pixel of the rectangle. Writes <ws>/edits/NAME/proxy.json (+ proxy.png, the rendered albedo "
        "projected onto it) and edit.json (edit view, rectangle, the surface in world coordinates).")
    _common(p)
    p.add_argument("--view", required=True, help="edit view name (e.g. frame_0009.png)")
    p.add_argument("--rect", type=opt.number(), nargs=4, required=True, metavar=("X0", "Y0", "X1", "Y1"),
                   help="rectangle in pixels of the view (origin top-left, x right, y down)")
    p.add_argument("--name", default=kind, help=f"edit name (folder under <ws>/edits, default {kind})")
    p.add_argument("--out", default=None, help="proxy.json path (default <ws>/edits/NAME/proxy.json)")
    p.add_argument("--color", default=None, help="flat linear colour r,g,b instead of the projected albedo texture")
    p.add_argument("--threshold", type=opt.POSITIVE, default=None,
                   help="RANSAC inlier distance in world units (default: 2%% of the selection's robust size)")
    p.add_argument("--min-selected", type=opt.COUNT, default=FitConfig.min_selected,
                   help=f"fewest distinct Gaussians the rectangle must select (default {FitConfig.min_selected})")
    where = ("all the surface points (--grow-on) lying on the cylinder (the rest of the column seen from other views)"
             if kind == "cylinder" else "the surface points (--grow-on) lying on the plane around the rectangle (the "
             "rectangle widened by half its size on every side)")
    p.add_argument("--no-grow", dest="grow", action="store_false",
                   help=f"keep the rectangle's RANSAC fit; by default it is refined by least squares on {where}")
    p.add_argument("--grow-on", default="auto", choices=GROW_ON,
                   help="what the fit grows on: 'depth' = the training views' depth priors back-projected "
                   "(measured surface points), 'centres' = the albedo Gaussians' centres, 'auto' (default) = "
                   "depth when every training view has a depth prior")
    how = "moved along its normal to" if kind == "plane" else "resized about its fitted axis to"
    p.add_argument("--no-sweep", dest="sweep", action="store_false",
                   help=f"keep the {kind} at its fitted centres; by default it is {how} where the edit view's "
                   "albedo, projected onto it, best matches the field's renders in up to 8 training views that see "
                   "it (the centres sit behind the surface they draw)")
    p.set_defaults(func=lambda a: run_fit(a, kind))


def register(sub: argparse._SubParsersAction) -> None:
    edit = sub.add_parser("edit", help="edit the albedo: fit a plane/cylinder proxy, project, bake",
                          description="Edit the albedo field through a proxy mesh (plane, cylinder or any "
                          "UV-mapped mesh).")
    esub = edit.add_subparsers(dest="edit_command", metavar="EDIT_COMMAND")
    esub.required = True
    _add_fit(esub, "plane")
    _add_fit(esub, "cylinder")

    p = esub.add_parser("project", help="project the current albedo onto a proxy's UVs (the painting start image)",
                        description="Render the albedo from a view and project it onto the proxy's UV texture; "
                        "writes a proxy file referring to that texture.")
    _common(p)
    p.add_argument("--proxy", required=True, help="proxy.json")
    p.add_argument("--view", default=None, help="view to project from (default: the fit's view, else the best one)")
    p.add_argument("--out", default=None, help="output proxy.json (default <proxy dir>/projected.json)")
    p.add_argument("--texels-per-pixel", type=opt.number(0, 64, lo_open=True), default=2.0, help="texture resolution (default 2)")
    p.set_defaults(func=run_project)

    d = BakeConfig()
    p = esub.add_parser(
        "bake", help="bake a proxy (texture or colour) into the albedo Gaussians",
        description="Composite the proxy over the albedo rendered from the edit view and from virtual views "
        "around it (depth-tested), spawn albedo Gaussians on it, re-optimise the albedo field only. Writes "
        "<ws>/edits/NAME/{albedo.ply, proxy.json, bake.json}; <ws>/layers is left as it was.")
    _common(p)
    p.add_argument("--proxy", default=None, help="proxy.json (mesh with UVs and a texture or colour)")
    p.add_argument("--plane", default=None, help="plane.json (center, normal, u_axis, v_axis, size) instead of --proxy")
    p.add_argument("--texture", default=None, help="with --plane: texture image (sRGB PNG/JPEG)")
    p.add_argument("--color", default=None, help="with --plane: flat linear colour r,g,b")
    p.add_argument("--name", default=None, help="edit name (default: the proxy's edit folder or file stem)")
    p.add_argument("--view", default=None, help="edit view (default: the fit's, else the view seeing the proxy best)")
    p.add_argument("--views", type=opt.COUNT0, default=d.views, help=f"virtual views around the edit view (default {d.views}; "
                   "0 = single-view bake)")
    p.add_argument("--max-angle", type=opt.number(0, 180, lo_open=True), default=d.max_angle,
                   help=f"half-angle of the cap of virtual views in degrees (default {d.max_angle:g})")
    p.add_argument("--spawn-fraction", type=opt.number(0, 1), default=d.spawn_fraction,
                   help=f"new Gaussians at this fraction of the edit pixels (default {d.spawn_fraction:g})")
    p.add_argument("--iterations", type=opt.COUNT0, default=d.iterations, help=f"re-optimisation steps (default {d.iterations})")
    add_device_argument(p)
    p.add_argument("--capture-views", type=opt.COUNT0, default=d.capture_views,
                   help=f"training views that see the proxy, composited like the virtual views (default "
                        f"{d.capture_views})")
    p.add_argument("--anchor-views", type=opt.COUNT0, default=d.anchor_views,
                   help=f"training views supervised with the unedited albedo (default {d.anchor_views})")
    p.add_argument("--surface", default=d.surface, choices=("replace", "paint"),
                   help="old Gaussians on the proxy under the edit: replace them by the new ones (default) or "
                        "keep them painted with the edit's colour")
    p.add_argument("--supersample", type=opt.integer(1, 16), default=d.supersample,
                   help=f"proxy texture samples per pixel side (anti-aliasing; default {d.supersample})")
    p.add_argument("--edit-filter", type=opt.NON_NEGATIVE, default=d.edit_filter, metavar="PX2",
                   help=f"screen-space low-pass of the new Gaussians, pixels^2 (default {d.edit_filter}; "
                        "3DGS's 0.3 blurs textures with 1-2 px detail)")
    p.add_argument("--no-restrict", action="store_true",
                   help="let every albedo Gaussian change (default: only those under the edit and the new ones)")
    p.add_argument("--downscale", type=opt.DOWNSCALE, default=1.0, help="divide image sizes by this factor (default 1)")
    p.set_defaults(func=run_bake)
