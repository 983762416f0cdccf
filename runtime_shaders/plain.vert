// A plain shaded surface without subsurface scattering: the baseline of frame-time comparisons.
#include "surface_maps_vert.glsl"

in vec3 in_position;
in vec3 in_normal;
uniform mat4 u_model;
uniform mat3 u_normal_matrix;
uniform mat4 u_view_projection;
out vec3 v_normal;
out vec3 v_position;

void main() {
    vec4 world = u_model * vec4(in_position, 1.0);
    v_normal = u_normal_matrix * in_normal;
    v_position = world.xyz;
    pass_surface_maps();
    gl_Position = u_view_projection * world;
}
