// Final pass of every per-vertex technique: the scattered radiance the vertex stage computed,
// transmitted out through the surface towards the eye, plus the surface's own reflection.
#include "sss_common.glsl"
#include "surface_maps_frag.glsl"

in vec3 v_q;            // scattered radiance reaching the surface from inside (per unit F_t out)
in vec3 v_normal;
in vec3 v_position;
in vec3 v_light;        // direction towards the light, world space
in float v_irradiance;  // light irradiance at the vertex
uniform vec3 u_eye;
uniform float u_eta;
uniform float u_specular;   // weight of the surface reflection (0: scattering only)
uniform float u_shininess;
uniform vec3 u_diffuse;     // albedo of an extra Lambertian surface term (0: none)
out vec4 f_color;

void main() {
    vec3 n = surface_normal(sss_normalize(v_normal), v_position);
    // the base-colour texture modulates the scattered light where it leaves (post-scatter texturing:
    // the tables carry the material's own colour) and the Lambertian term
    vec3 albedo = surface_albedo();
    vec3 v = sss_normalize(u_eye - v_position);
    vec3 l = sss_normalize(v_light);
    vec3 radiance = albedo * v_q * fresnel_transmittance(u_eta, dot(n, v));
    radiance += surface_reflection(n, v, l, v_irradiance, u_eta, u_specular, u_shininess, u_diffuse * albedo);
    f_color = vec4(radiance, 1.0);
}
