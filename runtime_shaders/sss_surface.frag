// Final pass of every per-vertex technique: the scattered radiance the vertex stage computed,
// transmitted out through the surface towards the eye, plus the surface's own reflection.
#include "sss_common.glsl"

in vec3 v_q;            // scattered radiance reaching the surface from inside (per unit F_t out)
in vec3 v_normal;
in vec3 v_position;
in vec3 v_light;        // unit direction towards the light, world space
in float v_irradiance;  // light irradiance at the vertex
uniform vec3 u_eye;
uniform float u_eta;
uniform float u_specular;   // weight of the surface reflection (0: scattering only)
uniform float u_shininess;
out vec4 f_color;

void main() {
    vec3 n = normalize(v_normal);
    vec3 v = normalize(u_eye - v_position);
    vec3 radiance = v_q * fresnel_transmittance(u_eta, dot(n, v));
    radiance += u_specular * v_irradiance * surface_specular(n, v, normalize(v_light), u_eta, u_shininess);
    f_color = vec4(radiance, 1.0);
}
