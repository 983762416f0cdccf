// The screen technique's per-material tables (glTF materials[i].extras.sssbake.screen) as the
// gather reads them: the samples one texel each, the Rd profile on r = reach t².
#include "sss_common.glsl"

uniform sampler2D u_samples;     // K x 1 RGBA32F: offset x, y (mm), weight (mm²), 0
uniform sampler2D u_rd;          // T x 1 RGBA32F: Rd rgb (1/mm²) at r = u_reach_mm (i / (T - 1))², 0
uniform float u_reach_mm;

// Rd(r) per channel, linear between table entries (read with texelFetch, so no float-texture
// filtering is needed, which GLSL ES 3.00 lacks); zero beyond the table's reach.
vec3 screen_rd(float r_mm) {
    if (r_mm >= u_reach_mm) return vec3(0.0);
    int last = textureSize(u_rd, 0).x - 1;
    float x = sqrt(max(r_mm, 0.0) / u_reach_mm) * float(last);
    int i = min(int(x), last - 1);
    float f = x - float(i);
    return mix(texelFetch(u_rd, ivec2(i, 0), 0).rgb, texelFetch(u_rd, ivec2(i + 1, 0), 0).rgb, f);
}
