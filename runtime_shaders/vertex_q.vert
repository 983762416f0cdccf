// The same final pass for radiance computed elsewhere per vertex (the offline reference, or a
// technique evaluated on the CPU): in_q is the scattered radiance before the exit Fresnel.
in vec3 in_position;
in vec3 in_normal;
in vec3 in_q;
uniform mat4 u_model;
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
    vec3 to_light = u_point_light == 1 ? u_light - world.xyz : u_light;
    float dist = length(to_light);
    v_light = to_light / max(dist, 1e-30);
    v_irradiance = u_point_light == 1 ? u_intensity / max(dist * u_mm_per_unit * dist * u_mm_per_unit, 1e-30) : u_intensity;
    v_q = in_q;
    v_normal = normalize(transpose(inverse(mat3(u_model))) * in_normal);
    v_position = world.xyz;
    gl_Position = u_view_projection * world;
}
