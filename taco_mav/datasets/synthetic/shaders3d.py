"""GLSL 3.30 sources of the 3-D renderer (`render3d.py`).

VS / FS: the scene. Vertex attributes as in `scene3d.Mesh` (local ENU metres, unit normals, linear RGB,
material id, surface metres); `FS` compiles in two variants: with `#define GROUND` the ground plane's
(ground texture at the fragment's local x, y; season tint by material label), without it the objects'
(procedural facade windows every 3 m x 3.2 m, plaster/roof/leaf noise from a sine-free hash, contact
shadows of moving cars). Both light with sun (Lambert, shadow-map test with 2 x 2 PCF, a 0.12 m normal
offset) plus sky, and blend to the haze colour with distance (camera) or by a constant share (aerial).
SKY_*: a full-screen gradient from the horizon row up. DEPTH_*: the shadow map's depth-only pass.
"""

from __future__ import annotations

__all__ = ["VS", "FS", "SKY_VS", "SKY_FS", "DEPTH_VS", "DEPTH_FS"]

VS = """#version 330
uniform mat4 mvp; uniform mat4 light_mvp;
in vec3 in_pos; in vec3 in_nrm; in vec3 in_col; in float in_mat; in vec2 in_uv;
out vec3 v_pos; out vec3 v_nrm; out vec3 v_col; flat out int v_mat; out vec2 v_uv;
void main() {
  v_pos = in_pos; v_nrm = in_nrm; v_col = in_col; v_mat = int(in_mat + 0.5); v_uv = in_uv;
  gl_Position = mvp * vec4(in_pos, 1.0);
}"""

FS = """#version 330
in vec3 v_pos; in vec3 v_nrm; in vec3 v_col; flat in int v_mat; in vec2 v_uv;
uniform sampler2D ground_rgb; uniform sampler2D ground_mat; uniform sampler2DShadow shadow_map;
uniform mat4 light_mvp; uniform vec4 ground_xf; uniform vec3 ground_fill;
uniform vec3 sun_dir; uniform vec3 sun_rgb; uniform vec3 sky_rgb; uniform vec3 eye; uniform int ortho;
uniform vec3 ortho_view;
uniform float haze_m; uniform vec3 haze_rgb; uniform float haze_mix;
uniform vec3 grass_tint; uniform vec3 foliage_tint; uniform float exposure;
out vec4 frag;
float hash(vec3 p) {  // Hoskins' hash without sine (cheap on a software rasteriser)
  p = fract(p * 0.1031); p += dot(p, p.zyx + 31.32); return fract((p.x + p.y) * p.z); }
void main() {
  vec3 alb = v_col;
#ifdef GROUND
  {
    vec2 uv = vec2((v_pos.x - ground_xf.x) / ground_xf.z, (ground_xf.y - v_pos.y) / ground_xf.w);
    if (uv.x < 0.0 || uv.x > 1.0 || uv.y < 0.0 || uv.y > 1.0) { alb = ground_fill; }
    else {
      alb = texture(ground_rgb, uv).rgb;
      float m = texture(ground_mat, uv).r * 255.0;
      alb *= mix(vec3(1.0), grass_tint, m < 0.5 ? 1.0 : (abs(m - 9.0) < 0.5 ? 0.4 : 0.0));  // grass, yards
    }
  }
  vec3 n = vec3(0.0, 0.0, 1.0);
#else
  if (v_mat == 1) {
    vec2 w = v_uv; float fx = fract(w.x / 3.0); float fy = fract(w.y / 3.2);
    alb *= 0.93 + 0.14 * hash(floor(v_pos * 5.0));
    if (w.y > 0.9 && fx > 0.28 && fx < 0.72 && fy > 0.3 && fy < 0.8)
      alb = vec3(0.10, 0.12, 0.15) + 0.12 * hash(vec3(floor(w.x / 3.0), floor(w.y / 3.2), 1.0));
    if (w.y < 0.35) alb *= 0.6;
  } else if (v_mat == 2) {
    alb *= 0.92 + 0.16 * hash(floor(v_pos * 3.0));
  } else if (v_mat == 8) {
    vec2 uv = vec2((v_pos.x - ground_xf.x) / ground_xf.z, (ground_xf.y - v_pos.y) / ground_xf.w);
    frag = vec4(texture(ground_rgb, uv).rgb * sky_rgb * exposure * 0.9, 1.0); return;
  } else if (v_mat == 3) {
    alb *= foliage_tint * (0.65 + 0.7 * hash(floor(v_pos * 3.0)));
  }
  vec3 n = normalize(v_nrm);
  vec3 view = ortho == 1 ? ortho_view : normalize(eye - v_pos);
  if (dot(n, view) < 0.0) n = -n;
#endif
  vec4 lc = light_mvp * vec4(v_pos + n * 0.12, 1.0);
  vec3 sc = lc.xyz / lc.w * 0.5 + 0.5;
  float lit = 1.0;
  if (sc.x > 0.0 && sc.x < 1.0 && sc.y > 0.0 && sc.y < 1.0) lit = texture(shadow_map, vec3(sc.xy, sc.z - 0.0004));
  float ndl = max(dot(n, sun_dir), 0.0);
  vec3 light = sky_rgb * (0.75 + 0.25 * n.z) + sun_rgb * ndl * lit;
  vec3 c = alb * light * exposure;
  float d = ortho == 1 ? 0.0 : length(eye - v_pos);
  float a = 1.0 - (1.0 - haze_mix) * exp(-d / haze_m);
  frag = vec4(mix(c, haze_rgb, a), 1.0);
}"""

SKY_VS = """#version 330
in vec2 in_xy; out float v_y;
void main() { v_y = in_xy.y; gl_Position = vec4(in_xy, 0.9999, 1.0); }"""
SKY_FS = """#version 330
in float v_y; uniform float horizon_ndc; uniform vec3 zenith; uniform vec3 horizon; out vec4 frag;
void main() { float a = clamp((v_y - horizon_ndc) / max(1.0 - horizon_ndc, 1e-3), 0.0, 1.0);
  frag = vec4(mix(horizon, zenith, sqrt(a)), 1.0); }"""

DEPTH_VS = """#version 330
uniform mat4 mvp; in vec3 in_pos; void main() { gl_Position = mvp * vec4(in_pos, 1.0); }"""
DEPTH_FS = """#version 330
void main() { }"""
