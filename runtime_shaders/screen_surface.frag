// Screen technique (Mertens et al. 2003), final pass: the mesh again, each pixel reading the
// resolved B at its own pixel (the same camera rasterises the same triangles as the G-buffer), L = F_t(eta,
// n.v) B (B holds E's 1/pi), plus the surface's reflection. Drawn with plain.vert.
#include "sss_common.glsl"

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
out vec4 f_color;

void main() {
    vec3 n = sss_normalize(v_normal);
    vec3 v = sss_normalize(u_eye - v_position);
    float irradiance;
    vec3 l = sss_light(u_point_light, u_light, u_intensity, u_mm_per_unit, v_position, irradiance);
    vec3 b = texelFetch(u_scattered, ivec2(gl_FragCoord.xy), 0).rgb;
    vec3 radiance = b * fresnel_transmittance(u_eta, dot(n, v));
    radiance += surface_reflection(n, v, l, irradiance, u_eta, u_specular, u_shininess, u_diffuse);
    f_color = vec4(radiance, 1.0);
}
