// Final pass of the kernels technique, fragment stage: q = B_l(uv) + the interpolated vertex
// response, then the exit Fresnel and surface terms exactly as sss_surface.frag.
#include "sss_common.glsl"

in vec3 v_q;            // B_g + B_d, interpolated
in vec2 v_uv;
in vec3 v_normal;
in vec3 v_position;
in vec3 v_light;
in float v_irradiance;
uniform sampler2D u_local;  // rgb: B_l on covered texels, alpha: 1 there, 0 elsewhere; bilinear
uniform vec3 u_eye;
uniform float u_eta;
uniform float u_specular;
uniform float u_shininess;
uniform vec3 u_diffuse;
out vec4 f_color;

void main() {
    // Bilinear over covered texels only: dividing by the summed coverage drops the others' weights.
    vec4 local = texture(u_local, v_uv);
    vec3 q = v_q + (local.a > 0.0 ? local.rgb / local.a : vec3(0.0));
    vec3 n = sss_normalize(v_normal);
    vec3 v = sss_normalize(u_eye - v_position);
    vec3 l = sss_normalize(v_light);
    vec3 radiance = q * fresnel_transmittance(u_eta, dot(n, v));
    radiance += surface_reflection(n, v, l, v_irradiance, u_eta, u_specular, u_shininess, u_diffuse);
    f_color = vec4(radiance, 1.0);
}
