// Illumination map E of the kernels technique (pipeline/kernels_data.py step 1), per texel:
// F_t(eta, n.l) max(0, n.l) vis irradiance / pi, Schlick's F_t, vis from the shadow map.
#include "sss_common.glsl"

in vec3 v_position;
in vec3 v_normal;
uniform float u_eta;
uniform int u_point_light;
uniform vec3 u_light;
uniform float u_intensity;
uniform float u_mm_per_unit;
uniform mat4 u_light_view_projection;  // world -> the shadow map's clip space
uniform sampler2D u_shadow;            // depth from the light, compare mode off
uniform float u_shadow_offset;         // world distance a lookup moves off the surface
out float f_illumination;

// 1 where the light reaches p, 0 where the shadow map holds something nearer; points outside
// the light's frustum (a point light inside the bounding sphere) count as lit.
float kernels_visibility(vec3 p) {
    vec4 clip = u_light_view_projection * vec4(p, 1.0);
    if (clip.w <= 0.0) return 1.0;
    vec3 ndc = clip.xyz / clip.w;
    if (any(greaterThan(abs(ndc), vec3(1.0)))) return 1.0;
    vec3 s = 0.5 * ndc + 0.5;
    return s.z <= texture(u_shadow, s.xy).r ? 1.0 : 0.0;
}

void main() {
    vec3 n = sss_normalize(v_normal);
    float irradiance;
    vec3 l = sss_light(u_point_light, u_light, u_intensity, u_mm_per_unit, v_position, irradiance);
    float cos_i = max(dot(n, l), 0.0);
    // Off the surface along n and towards the light, so a lit surface does not shadow itself.
    float vis = cos_i > 0.0 ? kernels_visibility(v_position + u_shadow_offset * (n + l)) : 0.0;
    f_illumination = schlick_transmittance(u_eta, cos_i) * cos_i * vis * irradiance / SSS_PI;
}
