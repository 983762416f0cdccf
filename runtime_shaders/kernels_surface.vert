// Final pass of the kernels technique (pipeline/kernels_data.py step 5), vertex stage: the vertex
// response B_g + B_d of this render vertex's welded vertex, from the gather passes, and its atlas
// UV for the local response.
#include "sss_common.glsl"

in vec3 in_position;
in vec3 in_normal;
in vec2 in_uv;
in ivec2 in_vertex_texel;      // texel of the welded vertex in the per-vertex textures
uniform sampler2D u_direct;    // rgb: B_d
uniform sampler2D u_global;    // rgb: B_g
uniform mat4 u_model;
uniform mat3 u_normal_matrix;
uniform mat4 u_view_projection;
uniform int u_point_light;
uniform vec3 u_light;
uniform float u_intensity;
uniform float u_mm_per_unit;
out vec3 v_q;
out vec2 v_uv;
out vec3 v_normal;
out vec3 v_position;
out vec3 v_light;
out float v_irradiance;

void main() {
    vec4 world = u_model * vec4(in_position, 1.0);
    v_light = sss_light(u_point_light, u_light, u_intensity, u_mm_per_unit, world.xyz, v_irradiance);
    v_q = texelFetch(u_direct, in_vertex_texel, 0).rgb + texelFetch(u_global, in_vertex_texel, 0).rgb;
    v_uv = in_uv;
    v_normal = u_normal_matrix * in_normal;
    v_position = world.xyz;
    gl_Position = u_view_projection * world;
}
