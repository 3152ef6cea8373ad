"""GLSL of the viewport splat engine, built through Blender's ``gpu`` module (no torch, no backend).

The splat shader reproduces the backend's rasterizer (:mod:`backend.render.projection` and the
``cpu`` kernel) per Gaussian: EWA projection of the 3D covariance with the Jacobian clamped at 1.3x
the field of view, ``+ eps2d`` on the 2D covariance (and, for a layer trained in the ``antialiased``
raster mode, the opacity scaled by sqrt(det S / det(S + eps2d I))), the opacity-aware footprint outside which
alpha < 1/255, ``alpha = min(0.99, o exp(power))`` with contributions under 1/255 dropped, and SH
colours ``max(SH(dir) + 0.5, 0)`` seen from the camera centre. Each Gaussian is one screen-aligned
quad (6 vertices, no vertex data of its own: ``gl_VertexID / 6`` is its rank in the depth order),
blended back to front with premultiplied "over" into a float offscreen buffer, so the buffer holds
what the backend accumulates: colour (without background) and alpha. The one rule not reproduced
is the stop at transmittance 1e-4, which changes a pixel by less than 1e-4.

The composite shader turns the layer buffers into A * S + R (or one layer) in sRGB, with the edit
preview's proxy colour laid over the albedo where the proxy is in front of (or on) the albedo's
surface.
"""

from __future__ import annotations

import gpu

SPLAT_VERTEX = """
const float ALPHA_MIN = 1.0 / 255.0;
const float BOX_MARGIN = 0.01;

vec4 texel(sampler2D tex, int i) {
  return texelFetch(tex, ivec2(i % TEXTURE_WIDTH, i / TEXTURE_WIDTH), 0);
}

vec3 sh_color(int index, vec3 base, vec3 dir, int sh_degree) {
  // 3DGS's real SH basis (backend/render/sh.py), bands 1..sh_degree on top of the DC term.
  vec4 t[12];
  for (int k = 0; k < 12; k++) { t[k] = texel(sh_data, index * 12 + k); }
  float c[48];
  for (int k = 0; k < 12; k++) { c[4 * k] = t[k].x; c[4 * k + 1] = t[k].y; c[4 * k + 2] = t[k].z; c[4 * k + 3] = t[k].w; }
  float x = dir.x, y = dir.y, z = dir.z;
  float b[15];
  b[0] = -0.4886025119029199 * y; b[1] = 0.4886025119029199 * z; b[2] = -0.4886025119029199 * x;
  float xx = x * x, yy = y * y, zz = z * z;
  b[3] = 1.0925484305920792 * x * y; b[4] = -1.0925484305920792 * y * z;
  b[5] = 0.31539156525252005 * (2.0 * zz - xx - yy); b[6] = -1.0925484305920792 * x * z;
  b[7] = 0.5462742152960396 * (xx - yy);
  b[8] = -0.5900435899266435 * y * (3.0 * xx - yy); b[9] = 2.890611442640554 * x * y * z;
  b[10] = -0.4570457994644658 * y * (4.0 * zz - xx - yy); b[11] = 0.3731763325901154 * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
  b[12] = -0.4570457994644658 * x * (4.0 * zz - xx - yy); b[13] = 1.445305721320277 * z * (xx - yy);
  b[14] = -0.5900435899266435 * x * (xx - 3.0 * yy);
  int n = sh_degree >= 3 ? 15 : (sh_degree == 2 ? 8 : 3);
  vec3 col = base;
  for (int k = 0; k < n; k++) { col += b[k] * vec3(c[3 * k], c[3 * k + 1], c[3 * k + 2]); }
  return max(col, vec3(0.0));
}

void main() {
  int rank = gl_VertexID / 6;
  int corner = gl_VertexID % 6;
  int index = int(texel(order, rank).x);
  vec4 g0 = texel(geometry, index * 4);
  vec4 g1 = texel(geometry, index * 4 + 1);
  vec4 g2 = texel(geometry, index * 4 + 2);
  vec4 g3 = texel(geometry, index * 4 + 3);
  gl_Position = vec4(0.0, 0.0, 2.0, 1.0);  // outside the clip volume: culled
  v_opacity = 0.0;
  v_mean = vec2(0.0);
  v_conic = vec3(0.0);
  v_color = vec3(0.0);

  vec3 p = (world_to_camera * vec4(g0.xyz, 1.0)).xyz;
  if (!(p.z > frame.z && p.z < frame.w)) { return; }
  float fx = intrinsics.x, fy = intrinsics.y, cx = intrinsics.z, cy = intrinsics.w;
  float W = frame.x, H = frame.y;
  float tan_x = 0.5 * W / fx, tan_y = 0.5 * H / fy;
  float uc = clamp(p.x / p.z, -(cx / fx + 0.3 * tan_x), (W - cx) / fx + 0.3 * tan_x);
  float vc = clamp(p.y / p.z, -(cy / fy + 0.3 * tan_y), (H - cy) / fy + 0.3 * tan_y);
  mat3 Wr = mat3(world_to_camera);
  // Rows of J (2x3) times Wr: T = J Wr
  vec3 j0 = vec3(fx / p.z, 0.0, -fx * uc / p.z);
  vec3 j1 = vec3(0.0, fy / p.z, -fy * vc / p.z);
  vec3 t0 = transpose(Wr) * j0;  // row 0 of J Wr
  vec3 t1 = transpose(Wr) * j1;
  mat3 S = mat3(g1.x, g1.y, g1.z, g1.y, g1.w, g2.x, g1.z, g2.x, g2.y);
  float a0 = dot(t0, S * t0);
  float b = dot(t0, S * t1);
  float c0 = dot(t1, S * t1);
  float a = a0 + g2.z;
  float c = c0 + g2.z;
  float det = a * c - b * b;
  float o = g0.w;
  if (g2.w > 0.5) {  // antialiased raster mode: the low-pass keeps the Gaussian's integral
    float det0 = a0 * c0 - b * b;
    o *= det0 > 1e-12 ? sqrt(det0 / det) : 0.0;
  }
  if (!(det > 0.0) || o * 255.0 <= 1.0) { return; }
  float k = sqrt(2.0 * log(o * 255.0));
  vec2 mean = vec2(fx * p.x / p.z + cx, fy * p.y / p.z + cy);
  vec2 half_extent = k * sqrt(vec2(a, c)) + BOX_MARGIN;
  vec2 off = vec2((corner == 1 || corner == 2 || corner == 4) ? 1.0 : -1.0,
                  (corner == 2 || corner == 4 || corner == 5) ? 1.0 : -1.0);
  vec2 pix = mean + off * half_extent;
  gl_Position = vec4(2.0 * pix.x / W - 1.0, 1.0 - 2.0 * pix.y / H, 0.0, 1.0);
  v_mean = mean;
  v_conic = vec3(c, -b, a) / det;
  v_opacity = o;
  int sh_degree = int(center_degree.w) % 4;
  if (int(center_degree.w) >= 4) {  // the depth feature
    v_color = vec3(p.z, 0.0, 0.0);
  } else if (sh_degree > 0) {
    v_color = sh_color(index, g3.xyz, normalize(g0.xyz - center_degree.xyz), sh_degree);
  } else {
    v_color = g3.xyz;
  }
}
"""

SPLAT_FRAGMENT = """
void main() {
  // Pixel centre in the backend's convention: x right, y down, (i + 0.5, j + 0.5)
  vec2 d = vec2(gl_FragCoord.x, frame.y - gl_FragCoord.y) - v_mean;
  float power = -0.5 * (v_conic.x * d.x * d.x + v_conic.z * d.y * d.y) - v_conic.y * d.x * d.y;
  if (power > 0.0) { discard; }
  float alpha = min(0.99, v_opacity * exp(power));
  if (alpha < 1.0 / 255.0) { discard; }
  frag = vec4(v_color * alpha, alpha);
}
"""

FULLSCREEN_VERTEX = """
void main() {
  // One triangle covering the screen; uv in [0, 1] over the viewport
  vec2 p = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));
  uv = p;
  gl_Position = vec4(2.0 * p - 1.0, 0.0, 1.0);
}
"""

COMPOSITE_FRAGMENT = """
vec3 to_srgb(vec3 c) {
  c = clamp(c, 0.0, 1.0);
  return mix(12.92 * c, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, step(vec3(0.0031308), c));
}

void main() {
  vec4 A = texture(albedo, uv);
  vec4 S = texture(shading, uv);
  vec4 R = texture(residual, uv);
  vec3 a = A.rgb;
  if (preview == 1) {
    // The proxy's colour over the albedo where the proxy is in front of (or on) the albedo surface:
    // the albedo's expected depth is its blended z over its alpha.
    vec4 P = texture(proxy_color, uv);
    vec4 PD = texture(proxy_depth, uv);
    float za = A.a > 0.05 ? texture(albedo_depth, uv).r / A.a : 1e30;
    if (PD.g > 0.5 && PD.r <= za * (1.0 + depth_tolerance)) {
      a = mix(a, P.rgb * max(A.a, P.a), P.a);
    }
  }
  vec3 lin;
  float cover = max(A.a, S.a);
  if (mode == 0) { lin = a * S.rgb + R.rgb; }
  else if (mode == 1) { lin = a; cover = A.a; }
  else if (mode == 2) { lin = S.rgb; cover = S.a; }
  else { lin = R.rgb; cover = R.a; }
  // The 3D view's framebuffer is sRGB-encoded by the GPU on write (Blender draws its overlays into an
  // sRGB target), so linear values clipped to [0, 1] display as the sRGB of igs render's images.
  frag = encode_srgb == 1 ? vec4(to_srgb(lin), cover) : vec4(clamp(lin, 0.0, 1.0), cover);
}
"""

PROXY_VERTEX = """
void main() {
  vec4 p = world_to_camera * vec4(pos, 1.0);
  v_z = p.z;
  v_uv = uv_in;
  // Same pixel mapping as the splats; depth for the proxy's own depth test in [near, far)
  float x = intrinsics.x * p.x / p.z + intrinsics.z;
  float y = intrinsics.y * p.y / p.z + intrinsics.w;
  float zn = clamp((p.z - frame.z) / (frame.w - frame.z), 0.0, 1.0);
  gl_Position = vec4((2.0 * x / frame.x - 1.0) * p.z, (1.0 - 2.0 * y / frame.y) * p.z,
                     (2.0 * zn - 1.0) * p.z, p.z);
}
"""

PROXY_FRAGMENT = """
void main() {
  if (v_z <= frame.z) { discard; }
  if (options.z > 0.5) { frag = vec4(v_z, 1.0, 0.0, 1.0); return; }  // the depth feature
  vec4 c = options.y > 0.5 ? texture(image, v_uv) : color;
  frag = vec4(c.rgb, c.a * options.x);
}
"""


def _splat_shader() -> gpu.types.GPUShader:
    iface = gpu.types.GPUStageInterfaceInfo("igs_splat_iface")
    iface.flat("VEC2", "v_mean")
    iface.flat("VEC3", "v_conic")
    iface.flat("FLOAT", "v_opacity")
    iface.flat("VEC3", "v_color")
    info = gpu.types.GPUShaderCreateInfo()
    info.define("TEXTURE_WIDTH", "4096")
    info.vertex_in(0, "FLOAT", "unused")
    info.vertex_out(iface)
    info.sampler(0, "FLOAT_2D", "geometry")
    info.sampler(1, "FLOAT_2D", "order")
    info.sampler(2, "FLOAT_2D", "sh_data")
    # Packed into 112 bytes: Blender guarantees 128 bytes of push constants
    info.push_constant("MAT4", "world_to_camera")
    info.push_constant("VEC4", "intrinsics")  # fx fy cx cy
    info.push_constant("VEC4", "frame")  # width height near far
    info.push_constant("VEC4", "center_degree")  # camera centre xyz, SH degree + 4 for the depth feature
    info.fragment_out(0, "VEC4", "frag")
    info.vertex_source(SPLAT_VERTEX)
    info.fragment_source(SPLAT_FRAGMENT)
    return gpu.shader.create_from_info(info)


def _composite_shader() -> gpu.types.GPUShader:
    iface = gpu.types.GPUStageInterfaceInfo("igs_composite_iface")
    iface.smooth("VEC2", "uv")
    info = gpu.types.GPUShaderCreateInfo()
    info.vertex_in(0, "FLOAT", "unused")
    info.vertex_out(iface)
    for slot, name in enumerate(("albedo", "albedo_depth", "shading", "residual", "proxy_color", "proxy_depth")):
        info.sampler(slot, "FLOAT_2D", name)
    info.push_constant("INT", "mode")
    info.push_constant("INT", "preview")
    info.push_constant("FLOAT", "depth_tolerance")
    info.push_constant("INT", "encode_srgb")
    info.fragment_out(0, "VEC4", "frag")
    info.vertex_source(FULLSCREEN_VERTEX)
    info.fragment_source(COMPOSITE_FRAGMENT)
    return gpu.shader.create_from_info(info)


def _proxy_shader() -> gpu.types.GPUShader:
    iface = gpu.types.GPUStageInterfaceInfo("igs_proxy_iface")
    iface.smooth("FLOAT", "v_z")
    iface.smooth("VEC2", "v_uv")
    info = gpu.types.GPUShaderCreateInfo()
    info.vertex_in(0, "VEC3", "pos")
    info.vertex_in(1, "VEC2", "uv_in")
    info.vertex_out(iface)
    info.sampler(0, "FLOAT_2D", "image")
    info.push_constant("MAT4", "world_to_camera")
    info.push_constant("VEC4", "intrinsics")  # fx fy cx cy
    info.push_constant("VEC4", "frame")  # width height near far
    info.push_constant("VEC4", "color")  # linear RGBA without an image
    info.push_constant("VEC4", "options")  # opacity, image (1) or colour (0), depth feature (1), unused
    info.fragment_out(0, "VEC4", "frag")
    info.vertex_source(PROXY_VERTEX)
    info.fragment_source(PROXY_FRAGMENT)
    return gpu.shader.create_from_info(info)


_CACHE: dict[str, gpu.types.GPUShader] = {}


def shader(name: str) -> gpu.types.GPUShader:
    """The compiled ``splat``, ``composite`` or ``proxy`` shader (compiled once per session)."""
    if name not in _CACHE:
        _CACHE[name] = {"splat": _splat_shader, "composite": _composite_shader, "proxy": _proxy_shader}[name]()
    return _CACHE[name]
