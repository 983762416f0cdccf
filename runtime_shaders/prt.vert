// prt runtime (Hao & Varshney 2004), per vertex like the paper: decode q at the light direction
// and scale by the light's irradiance.
#include "sss_common.glsl"
#include "prt_decode.glsl"
#include "surface_maps_vert.glsl"

in vec3 in_position;
in vec3 in_normal;
// (the per-vertex prt attributes are declared in prt_decode.glsl)
uniform mat4 u_model;          // object -> world
uniform mat3 u_normal_matrix;  // inverse transpose of u_model's linear part
uniform mat3 u_world_to_object;// inverse of u_model's linear part: q is tabulated in object space
uniform mat4 u_view_projection;
uniform int u_point_light;     // 0: directional, 1: point
uniform vec3 u_light;          // direction towards a directional light, or a point light's position
uniform float u_intensity;
uniform float u_mm_per_unit;   // world units -> mm, for the point light's falloff
out vec3 v_q;
out vec3 v_normal;
out vec3 v_position;
out vec3 v_light;
out float v_irradiance;

void main() {
    vec4 world = u_model * vec4(in_position, 1.0);
    v_light = sss_light(u_point_light, u_light, u_intensity, u_mm_per_unit, world.xyz, v_irradiance);
    vec3 l_object = sss_normalize(u_world_to_object * v_light);
    // Negative q is compression error, not light.
    v_q = v_irradiance * max(prt_decode(gl_VertexID, l_object), vec3(0.0));
    v_normal = u_normal_matrix * in_normal;
    v_position = world.xyz;
    pass_surface_maps();
    gl_Position = u_view_projection * world;
}
