// lpv injection, first pass: the shadow map from the light holds, per texel, the object-space
// point it sees and its unit normal (a reflective shadow map without the reflected flux: the
// transmitted flux follows from the texel, pipeline/lpv_inject.py). Drawn with lpv_rsm.vert.
in vec3 v_object;
in vec3 v_object_normal;
layout(location = 0) out vec4 f_point;    // xyz: object-space position; w: 1 (covered)
layout(location = 1) out vec4 f_normal;   // xyz: object-space unit normal

void main() {
    f_point = vec4(v_object, 1.0);
    float len = length(v_object_normal);
    f_normal = vec4(len > 0.0 ? v_object_normal / len : vec3(0.0), 0.0);
}
