// Illumination map E of the kernels technique (pipeline/kernels_data.py step 1), per texel:
// F_t(eta, n.l) max(0, n.l) vis irradiance / pi, Schlick's F_t, vis from the shadow map.
#include "sss_common.glsl"
#include "shadow.glsl"

in vec3 v_position;
in vec3 v_normal;
uniform float u_eta;
uniform int u_point_light;
uniform vec3 u_light;
uniform float u_intensity;
uniform float u_mm_per_unit;
out float f_illumination;

void main() {
    vec3 n = sss_normalize(v_normal);
    float irradiance;
    vec3 l = sss_light(u_point_light, u_light, u_intensity, u_mm_per_unit, v_position, irradiance);
    float cos_i = max(dot(n, l), 0.0);
    f_illumination = schlick_transmittance(u_eta, cos_i) * cos_i * surface_visibility(v_position, n, l) *
                     irradiance / SSS_PI;
}
