// Screen technique (Mertens et al. 2003), G-buffer pass: from the camera, each pixel's world position and
// the irradiance entering there, E = F_t(eta, n.l) max(0, n.l) vis irradiance / pi (exact F_t,
// vis from the shadow map), and its unit normal with a coverage flag. Drawn with plain.vert.
#include "sss_common.glsl"
#include "shadow.glsl"
#include "surface_maps_frag.glsl"

in vec3 v_position;
in vec3 v_normal;
uniform float u_eta;
uniform int u_point_light;
uniform vec3 u_light;
uniform float u_intensity;
uniform float u_mm_per_unit;
layout(location = 0) out vec4 f_position;  // xyz: world position; w: E
layout(location = 1) out vec4 f_normal;    // xyz: unit world normal; w: 1 (covered)

void main() {
    vec3 n = sss_normalize(v_normal);
    float irradiance;
    vec3 l = sss_light(u_point_light, u_light, u_intensity, u_mm_per_unit, v_position, irradiance);
    // the normal map tilts where light enters; the gather's tangent frame keeps the geometric normal
    float cos_i = max(dot(surface_normal(n, v_position), l), 0.0);
    float e = fresnel_transmittance(u_eta, cos_i) * cos_i * surface_visibility(v_position, n, l) * irradiance / SSS_PI;
    f_position = vec4(v_position, e);
    f_normal = vec4(n, 1.0);
}
