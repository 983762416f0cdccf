// lpv injection, second pass: one point per shadow-map texel (no attributes, gl_VertexID), sent to
// the cell its surface point lies in (a hair inside) in the flattened grid, carrying the texel's
// transmitted flux T Φ as a clamped-cosine lobe about the refracted direction: coefficients
// T Φ (y00, (2/3) y1m(ω_t)) (pipeline/lpv_inject.py). Additive blending sums a cell's texels.
#include "sss_common.glsl"
#include "lpv_grid.glsl"

uniform sampler2D u_points;      // lpv_rsm.frag's targets
uniform sampler2D u_normals;
uniform int u_size;              // shadow-map texels per side
uniform int u_point_light;
uniform vec3 u_light;            // object space: direction towards a directional light, or a point light's position
uniform float u_intensity;       // irradiance (directional) or intensity (point)
uniform float u_texel_mm2;       // directional: a texel's area across the beam, mm²
uniform float u_tan_half;        // point: tan(half field of view) of the map
uniform float u_eta;
uniform vec3 u_origin;           // grid corner, object space
uniform float u_cell;            // cell side, object units
out vec4 v_lobe;

void main() {
    ivec2 texel = ivec2(gl_VertexID % u_size, gl_VertexID / u_size);
    vec4 point = texelFetch(u_points, texel, 0);
    vec3 n = texelFetch(u_normals, texel, 0).xyz;
    gl_PointSize = 1.0;
    v_lobe = vec4(0.0);
    gl_Position = vec4(2.0, 2.0, 0.0, 1.0);  // outside the viewport unless the texel saw the surface
    if (point.w == 0.0) return;
    vec3 towards = u_point_light == 1 ? normalize(u_light - point.xyz) : normalize(u_light);
    float flux = u_intensity * u_texel_mm2;
    if (u_point_light == 1) {
        // Δω = A cos θ / r² of the texel on a plane at distance 1 (cos θ = 1 / r)
        vec2 uv = (vec2(texel) + 0.5) / float(u_size) * 2.0 - 1.0;
        float r2 = 1.0 + u_tan_half * u_tan_half * dot(uv, uv);
        float side = 2.0 * u_tan_half / float(u_size);
        flux = u_intensity * side * side / (r2 * sqrt(r2));
    }
    float cos_i = clamp(dot(n, towards), 0.0, 1.0);
    float cos_t = sqrt(clamp(1.0 - (1.0 - cos_i * cos_i) / (u_eta * u_eta), 0.0, 1.0));
    vec3 omega = sss_normalize(-towards / u_eta + (cos_i / u_eta - cos_t) * n);
    float carried = fresnel_transmittance(u_eta, cos_i) * flux;
    // basis order (c00, c1-1, c10, c11): y00 = 1/√(4π), y1m = √(3/(4π)) (y, z, x)
    v_lobe = carried * vec4(0.28209479177387814, 2.0 / 3.0 * 0.4886025119029199 * omega.yzx);
    ivec3 cell = ivec3(floor((point.xyz - 1e-3 * u_cell * n - u_origin) / u_cell));
    if (!lpv_inside(cell)) return;
    vec2 target = vec2(lpv_texel(cell)) + 0.5;
    gl_Position = vec4(target / vec2(u_grid.x, u_grid.y * u_grid.z) * 2.0 - 1.0, 0.0, 1.0);
}
