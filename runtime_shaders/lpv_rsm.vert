// lpv injection, first pass, vertex stage: object-space position and normal to the fragments.
in vec3 in_position;
in vec3 in_normal;
uniform mat4 u_model;
uniform mat4 u_view_projection;   // the light's
out vec3 v_object;
out vec3 v_object_normal;

void main() {
    v_object = in_position;
    v_object_normal = in_normal;
    gl_Position = u_view_projection * u_model * vec4(in_position, 1.0);
}
