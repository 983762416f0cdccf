// Screen technique, resolve pass: the interleaved sampling's resolve (Keller & Heidrich 2001). Each
// pixel of an n x n tile turned the sample pattern by its own angle; averaging B over the n x n
// window around a pixel, which holds every angle once, gathers with n² N samples at the cost of a
// blur of n pixels. Neighbours across a discontinuity would mix unrelated surface: only those
// within u_resolve_mm of x_o, facing its way, are averaged.
uniform sampler2D u_gathered;   // gather pass: rgb B, a: share found
uniform sampler2D u_position;   // G-buffer: xyz world position
uniform sampler2D u_normal;     // G-buffer: xyz unit normal, w: coverage
uniform int u_interleave;       // n
uniform float u_mm_per_world;
uniform float u_resolve_mm;
out vec4 f_scattered;

void main() {
    ivec2 pixel = ivec2(gl_FragCoord.xy);
    vec4 here = texelFetch(u_normal, pixel, 0);
    if (here.w == 0.0) {
        f_scattered = vec4(0.0);
        return;
    }
    vec3 x_o = texelFetch(u_position, pixel, 0).xyz;
    ivec2 last = textureSize(u_gathered, 0) - 1;
    int low = -((u_interleave - 1) / 2);
    vec4 sum = vec4(0.0);
    float count = 0.0;
    for (int dy = 0; dy < u_interleave; ++dy) {
        for (int dx = 0; dx < u_interleave; ++dx) {
            ivec2 q = clamp(pixel + ivec2(low + dx, low + dy), ivec2(0), last);
            vec4 normal = texelFetch(u_normal, q, 0);
            vec3 p = texelFetch(u_position, q, 0).xyz;
            if (normal.w == 0.0 || dot(normal.xyz, here.xyz) < 0.5 ||
                length(p - x_o) * u_mm_per_world > u_resolve_mm) continue;
            sum += texelFetch(u_gathered, q, 0);
            count += 1.0;
        }
    }
    f_scattered = sum / count;  // count >= 1: the pixel itself
}
