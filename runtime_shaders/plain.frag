// Lambert plus the dielectric specular lobe, lit per pixel; no subsurface scattering.
#include "sss_common.glsl"
#include "surface_maps_frag.glsl"

in vec3 v_normal;
in vec3 v_position;
uniform vec3 u_eye;
uniform float u_eta;
uniform float u_specular;
uniform float u_shininess;
uniform vec3 u_diffuse;     // albedo
uniform int u_point_light;
uniform vec3 u_light;
uniform float u_intensity;
uniform float u_mm_per_unit;
out vec4 f_color;

void main() {
    vec3 n = surface_normal(sss_normalize(v_normal), v_position);
    vec3 v = sss_normalize(u_eye - v_position);
    float irradiance;
    vec3 l = sss_light(u_point_light, u_light, u_intensity, u_mm_per_unit, v_position, irradiance);
    f_color = vec4(surface_reflection(n, v, l, irradiance, u_eta, u_specular, u_shininess,
                                         u_diffuse * surface_albedo()), 1.0);
}
