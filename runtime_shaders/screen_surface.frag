// Screen technique (Mertens et al. 2003), final pass: the mesh again, each pixel reading the
// resolved B at its own pixel (the same camera rasterises the same triangles as the G-buffer), L = F_t(eta,
// n.v) B (B holds E's 1/pi), plus the surface's reflection. Drawn with plain.vert. The three.js runtime adds (SSS_TRANSMISSION) the light a thin
// part transmits from a light behind it, an extension to the paper, which gathers reflection only:
// the diffuse transmission of the file's standard fallback (pipeline/bake/fallback.py: T(d) of a
// slab of the median thickness d, the KHR_materials_diffuse_transmission lobe (1 - t) f c), taken
// to the local baked thickness x by the diffusion extinction of its KHR_materials_volume:
// T(x) = min(1, T(d) e^(-sigma_tr (x - d))), lit as that lobe is, max(0, -n.l) irradiance / pi.
#include "sss_common.glsl"
#include "surface_maps_frag.glsl"

in vec3 v_normal;
in vec3 v_position;
uniform sampler2D u_scattered;   // rgb: B (gather, resolved)
uniform vec3 u_eye;
uniform float u_eta;
uniform float u_specular;
uniform float u_shininess;
uniform vec3 u_diffuse;
uniform int u_point_light;
uniform vec3 u_light;
uniform float u_intensity;
uniform float u_mm_per_unit;
#ifdef SSS_TRANSMISSION
in float v_thickness;           // mm
uniform vec3 u_transmittance;   // T(d) per channel
uniform vec3 u_sigma_tr;        // 1/mm
uniform float u_median_mm;      // d
#endif
out vec4 f_color;

void main() {
    vec3 n = surface_normal(sss_normalize(v_normal), v_position);
    vec3 albedo = surface_albedo();  // post-scatter, as sss_surface.frag
    vec3 v = sss_normalize(u_eye - v_position);
    float irradiance;
    vec3 l = sss_light(u_point_light, u_light, u_intensity, u_mm_per_unit, v_position, irradiance);
    vec3 b = texelFetch(u_scattered, ivec2(gl_FragCoord.xy), 0).rgb;
    vec3 radiance = albedo * b * fresnel_transmittance(u_eta, dot(n, v));
#ifdef SSS_TRANSMISSION
    vec3 through = min(u_transmittance * exp(-u_sigma_tr * (v_thickness - u_median_mm)), vec3(1.0));
    radiance += albedo * through * max(-dot(n, l), 0.0) * irradiance / SSS_PI;
#endif
    radiance += surface_reflection(n, v, l, irradiance, u_eta, u_specular, u_shininess, u_diffuse * albedo);
    f_color = vec4(radiance, 1.0);
}
