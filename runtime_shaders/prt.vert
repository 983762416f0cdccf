// prt runtime (Hao & Varshney 2004), per vertex like the paper: decode q at the light direction
// and scale by the light's irradiance. Directional light: u_light is the unit direction towards
// it; point light: its position (world), irradiance falling as 1/d^2 with d in mm.
#include "prt_decode.glsl"

in vec3 in_position;
in vec3 in_normal;
in uvec2 in_prt_ref;
in ivec2 in_prt_w;
uniform mat4 u_model;          // object -> world
uniform mat4 u_view_projection;
uniform int u_point_light;     // 0: directional, 1: point
uniform vec3 u_light;
uniform float u_intensity;
uniform float u_mm_per_unit;   // world units -> mm, for the point light's falloff
out vec3 v_q;
out vec3 v_normal;
out vec3 v_position;
out vec3 v_light;
out float v_irradiance;

void main() {
    vec4 world = u_model * vec4(in_position, 1.0);
    mat3 linear = mat3(u_model);
    vec3 to_light = u_point_light == 1 ? u_light - world.xyz : u_light;
    float dist = length(to_light);
    vec3 l_world = to_light / max(dist, 1e-30);
    v_irradiance = u_point_light == 1 ? u_intensity / max(dist * u_mm_per_unit * dist * u_mm_per_unit, 1e-30) : u_intensity;
    // q is tabulated in object space: take the light direction there.
    vec3 l_object = normalize(inverse(linear) * l_world);
    v_q = v_irradiance * max(prt_decode(gl_VertexID, in_prt_ref, in_prt_w, l_object), vec3(0.0));
    v_normal = normalize(transpose(inverse(linear)) * in_normal);
    v_position = world.xyz;
    v_light = l_world;
    gl_Position = u_view_projection * world;
}
