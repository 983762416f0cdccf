// Screen technique (Mertens et al. 2003), gather pass, per pixel x_o of the G-buffer: the dipole
// integral B(x_o) = ∫ Rd(|x_o - p|) E(p) dA_p from samples p'_i = x_o + offset_i on the tangent
// plane, projected through the camera onto the surface p_i (the G-buffer pixel under p'_i):
//
//     B ≈ Σ_i Rd(r_i) E(p_i) w_i J_i,   r_i = |offset_i|, or |p_i - x_o| where p_i lies farther
//                                      off than the pixel grid explains,
//
// w_i the precomputed balance-heuristic weights (pipeline/screen_samples.py), J_i the optional
// Jacobian |dA_p / dA_p'| = (cos θ' / cos θ) (d² / d'²) of the projection from the eye e (θ, θ':
// angles between the eye ray and the normals at p and p'; d, d': distances from e), which the
// paper omits. The pattern turns by a per-pixel angle from an interleaved tile, which trades the
// pattern's structure for noise and keeps each pixel's estimate unbiased.
//
// Missing surface (samples off the image, on the background, or on another part of the object far
// from x_o) lowers F = Σ_i Rd(r_i) w_i J_i, the estimate of Rd's integral over what was found, below
// R_d. With u_fill, B is scaled by R_d / F: the unseen surface is taken to be lit like the found
// one (exact under uniform light on any shape).
#include "sss_common.glsl"
#include "screen_tables.glsl"

uniform sampler2D u_position;   // G-buffer: xyz world position, w: E
uniform sampler2D u_normal;     // G-buffer: xyz unit normal, w: coverage
uniform mat4 u_view_projection; // the camera's, world -> clip
uniform vec3 u_eye;
uniform float u_mm_per_world;
uniform int u_count;            // samples in u_samples (N + U)
uniform int u_jacobian;         // 1: weight by J_i
uniform int u_fill;             // 1: scale by R_d / F
uniform int u_interleave;       // side of the tile of pattern rotations (1: none)
uniform vec3 u_total;           // R_d per channel
out vec4 f_scattered;           // rgb: B; a: the smallest share F / R_d over the channels

// An orthonormal tangent frame of unit n (Duff et al. 2017, branchless).
void tangent_frame(vec3 n, out vec3 t, out vec3 b) {
    float s = n.z >= 0.0 ? 1.0 : -1.0;
    float a = -1.0 / (s + n.z);
    float c = n.x * n.y * a;
    t = vec3(1.0 + s * n.x * n.x * a, s * c, -s * n.x);
    b = vec3(c, s + n.y * n.y * a, -n.y);
}

void main() {
    ivec2 pixel = ivec2(gl_FragCoord.xy);
    vec4 here = texelFetch(u_normal, pixel, 0);
    if (here.w == 0.0) {
        f_scattered = vec4(0.0);
        return;
    }
    vec3 x_o = texelFetch(u_position, pixel, 0).xyz;
    vec3 n = here.xyz;
    vec3 t, b;
    tangent_frame(n, t, b);
    ivec2 tile = pixel % u_interleave;
    float angle = 2.0 * SSS_PI * fract(float(tile.x + u_interleave * tile.y) * 0.6180339887498949);
    vec2 turn = vec2(cos(angle), sin(angle));
    vec2 size = vec2(textureSize(u_position, 0));
    // the tangent plane's pixel at x_o, mm (its coarser direction): how far a found sample's
    // distance can stray from its offset by the pixel grid alone
    vec4 c0 = u_view_projection * vec4(x_o, 1.0);
    float step_world = 1e-3 * length(u_eye - x_o);
    vec4 ct = u_view_projection * vec4(x_o + step_world * t, 1.0);
    vec4 cb = u_view_projection * vec4(x_o + step_world * b, 1.0);
    vec2 s0 = 0.5 * size * c0.xy / c0.w;
    float pixels = min(length(0.5 * size * ct.xy / ct.w - s0), length(0.5 * size * cb.xy / cb.w - s0));
    float footprint = 1.5 * step_world * u_mm_per_world / max(pixels, 1e-6);
    vec3 sum = vec3(0.0);
    vec3 found = vec3(0.0);
    for (int i = 0; i < u_count; ++i) {
        vec4 s = texelFetch(u_samples, ivec2(i, 0), 0);  // xy: offset (mm); z: weight (mm²)
        vec2 o = vec2(turn.x * s.x - turn.y * s.y, turn.y * s.x + turn.x * s.y);
        vec3 p_plane = x_o + (o.x * t + o.y * b) / u_mm_per_world;
        vec4 clip = u_view_projection * vec4(p_plane, 1.0);
        if (clip.w <= 0.0) continue;
        vec2 uv = 0.5 * clip.xy / clip.w + 0.5;
        if (any(lessThan(uv, vec2(0.0))) || any(greaterThanEqual(uv, vec2(1.0)))) continue;
        ivec2 q = ivec2(uv * size);
        vec4 normal = texelFetch(u_normal, q, 0);
        if (normal.w == 0.0) continue;
        vec4 p = texelFetch(u_position, q, 0);
        float jacobian = 1.0;
        if (u_jacobian == 1) {
            vec3 to_p = u_eye - p.xyz;
            vec3 to_plane = u_eye - p_plane;
            float d2 = dot(to_p, to_p), d2_plane = dot(to_plane, to_plane);
            float cos_p = abs(dot(normal.xyz, to_p)) / sqrt(d2);
            float cos_plane = abs(dot(n, to_plane)) / sqrt(d2_plane);
            // grazing views of p would weight one pixel without bound
            jacobian = cos_plane / max(cos_p, 0.05) * d2 / d2_plane;
        }
        // Where the surface was found where the offset points (within the pixel grid), Rd at the
        // offset's own radius, which its weight was drawn for; only surface found farther off (a
        // step in depth, another part) takes its real, larger distance. Read at pixel centres,
        // a sample inside x_o's own pixel would find r = 0 and Rd(0), a spike for light
        // scattered a few times near where it entered (the Monte Carlo profile's), and count
        // x_o's own irradiance many times over.
        float r_offset = length(s.xy);
        float r_found = length(p.xyz - x_o) * u_mm_per_world;
        float r_i = r_found > r_offset + footprint ? r_found : r_offset;
        vec3 rd = screen_rd(r_i) * (s.z * jacobian);
        sum += rd * p.w;
        found += rd;
    }
    vec3 scale = vec3(1.0);
    if (u_fill == 1) scale = mix(vec3(0.0), u_total / max(found, vec3(1e-30)), greaterThan(found, vec3(0.0)));
    vec3 share = found / u_total;
    f_scattered = vec4(sum * scale, min(min(share.r, share.g), share.b));
}
