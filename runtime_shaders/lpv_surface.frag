// lpv rendering, the final pass (drawn with plain.vert): the accumulated intensity around each
// pixel's surface point, trilinear between the cell centres over the cells with medium (weights
// renormalised), turned into radiance by the paper's area light,
// L_i = scale (2/A)(√(1/4π) c00 + ½ √(3/4π) c10^(n)), A the cell's cross-section (mm²), c10^(n)
// the l = 1 part along the outward normal, scale the grid's calibration for the step count
// (pipeline/lpv_calibrate.py); then the exit Fresnel and the surface's reflection.
#include "sss_common.glsl"
#include "lpv_grid.glsl"

in vec3 v_normal;
in vec3 v_position;
uniform sampler2D u_sum_red;     // the accumulation grid
uniform sampler2D u_sum_green;
uniform sampler2D u_sum_blue;
uniform mat4 u_model;
uniform mat3 u_world_to_object;  // the model's linear part, inverted
uniform mat3 u_object_normal;    // world normal -> object normal (unnormalised): the linear part transposed
uniform vec3 u_origin;
uniform float u_cell;
uniform vec3 u_scale;
uniform vec3 u_eye;
uniform float u_eta;
uniform float u_specular;
uniform float u_shininess;
uniform vec3 u_diffuse;
uniform int u_point_light;
uniform vec3 u_light;
uniform float u_intensity;
uniform float u_mm_per_unit;
out vec4 f_color;

void main() {
    vec3 n = sss_normalize(v_normal);
    vec3 v = sss_normalize(u_eye - v_position);
    float irradiance;
    vec3 l = sss_light(u_point_light, u_light, u_intensity, u_mm_per_unit, v_position, irradiance);
    vec3 p = u_world_to_object * (v_position - u_model[3].xyz);
    vec3 m = sss_normalize(u_object_normal * n);
    vec3 coords = (p - u_origin) / u_cell - 0.5;
    ivec3 base = ivec3(floor(coords));
    vec3 frac = coords - vec3(base);
    vec4 red = vec4(0.0), green = vec4(0.0), blue = vec4(0.0);
    float weight = 0.0;
    for (int corner = 0; corner < 8; ++corner) {
        ivec3 offset = ivec3(corner & 1, (corner >> 1) & 1, corner >> 2);
        ivec3 cell = base + offset;
        if (!lpv_inside(cell) || texelFetch(u_medium, lpv_texel(cell), 0).a == 0.0) continue;
        vec3 t = mix(1.0 - frac, frac, vec3(offset));
        float w = t.x * t.y * t.z;
        ivec2 at = lpv_texel(cell);
        red += w * texelFetch(u_sum_red, at, 0);
        green += w * texelFetch(u_sum_green, at, 0);
        blue += w * texelFetch(u_sum_blue, at, 0);
        weight += w;
    }
    vec3 inside = vec3(0.0);
    if (weight > 0.0) {
        vec4 along = vec4(0.28209479177387814, 0.5 * 0.4886025119029199 * m.yzx) / weight;  // basis (y, z, x)
        inside = max(u_scale * 2.0 / (u_cell_mm * u_cell_mm) * vec3(dot(red, along), dot(green, along),
                                                                    dot(blue, along)), 0.0);
    }
    vec3 radiance = inside * fresnel_transmittance(u_eta, dot(n, v));
    radiance += surface_reflection(n, v, l, irradiance, u_eta, u_specular, u_shininess, u_diffuse);
    f_color = vec4(radiance, 1.0);
}
