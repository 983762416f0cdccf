// Illumination-map pass of the kernels runtime: the mesh's triangles drawn at their atlas UVs, and
// border texels as one-pixel points at their centres, carrying world position and normal.
in vec3 in_position;
in vec3 in_normal;
in vec2 in_uv;                 // glTF convention: v down, v = 0 is atlas row 0 (the image's top)
uniform mat4 u_model;
uniform mat3 u_normal_matrix;
out vec3 v_position;
out vec3 v_normal;

void main() {
    v_position = (u_model * vec4(in_position, 1.0)).xyz;
    v_normal = u_normal_matrix * in_normal;
    // v = 0 goes to framebuffer row 0, which is texture row 0: the map's rows are atlas rows as
    // stored (row 0 first), which is also what texture(map, uv) reads for glTF UVs.
    gl_Position = vec4(2.0 * in_uv - 1.0, 0.0, 1.0);
    gl_PointSize = 1.0;  // ES leaves points without it undefined
}
