// Final pass of the kernels technique (pipeline/kernels_data.py step 5), vertex stage: the vertex
// response B_g + B_d of this render vertex's welded vertex, blended from the three global vertices
// it lies between (gather passes), and its atlas UV for the local response.
#include "sss_common.glsl"

in vec3 in_position;
in vec3 in_normal;
in vec2 in_uv;
in ivec2 in_global_texel0;     // texels of the three global vertices in the per-vertex textures
in ivec2 in_global_texel1;
in ivec2 in_global_texel2;
in vec3 in_global_weight;      // and their weights
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
    v_q = in_global_weight.x * (texelFetch(u_direct, in_global_texel0, 0).rgb + texelFetch(u_global, in_global_texel0, 0).rgb)
        + in_global_weight.y * (texelFetch(u_direct, in_global_texel1, 0).rgb + texelFetch(u_global, in_global_texel1, 0).rgb)
        + in_global_weight.z * (texelFetch(u_direct, in_global_texel2, 0).rgb + texelFetch(u_global, in_global_texel2, 0).rgb);
    v_uv = in_uv;
    v_normal = u_normal_matrix * in_normal;
    v_position = world.xyz;
    gl_Position = u_view_projection * world;
}
