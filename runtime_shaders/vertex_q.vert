// The same final pass for radiance computed elsewhere per vertex (the offline reference, or a
// technique evaluated on the CPU): in_q is the scattered radiance before the exit Fresnel,
// irradiance included.
#include "sss_common.glsl"

in vec3 in_position;
in vec3 in_normal;
in vec3 in_q;
uniform mat4 u_model;
uniform mat3 u_normal_matrix;
uniform mat4 u_view_projection;
uniform int u_point_light;
uniform vec3 u_light;
uniform float u_intensity;
uniform float u_mm_per_unit;
out vec3 v_q;
out vec3 v_normal;
out vec3 v_position;
out vec3 v_light;
out float v_irradiance;

void main() {
    vec4 world = u_model * vec4(in_position, 1.0);
    // The light still drives the surface terms of the fragment stage.
    v_light = sss_light(u_point_light, u_light, u_intensity, u_mm_per_unit, world.xyz, v_irradiance);
    v_q = in_q;
    v_normal = u_normal_matrix * in_normal;
    v_position = world.xyz;
    gl_Position = u_view_projection * world;
}
