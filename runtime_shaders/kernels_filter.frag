// Local response of the kernels technique (pipeline/kernels_data.py step 2), per atlas texel:
// B_l = sum_o kernels[s, o] E[row + dy_o, col + dx_o], taps outside the atlas reading 0.
// rgb: B_l; alpha: 1 on covered texels, 0 elsewhere (the final pass renormalises by it).
#include "kernels_tables.glsl"

uniform sampler2D u_illumination;   // R32F, W x H: E
uniform isampler2D u_texel_kernel;  // RG32I, W x H: texel of the first weight in u_kernels; x < 0: not covered
uniform sampler2D u_kernels;        // RGB32F: k * k weights per covered texel, offset o = (dy + r) k + (dx + r)
uniform int u_kernel_radius;        // r = (k - 1) / 2
out vec4 f_local;

void main() {
    ivec2 texel = ivec2(gl_FragCoord.xy);
    ivec2 entry = texelFetch(u_texel_kernel, texel, 0).xy;
    if (entry.x < 0) {
        f_local = vec4(0.0);
        return;
    }
    ivec2 size = textureSize(u_illumination, 0);
    int width = textureSize(u_kernels, 0).x;
    vec3 sum = vec3(0.0);
    for (int dy = -u_kernel_radius; dy <= u_kernel_radius; ++dy) {
        for (int dx = -u_kernel_radius; dx <= u_kernel_radius; ++dx) {
            ivec2 tap = texel + ivec2(dx, dy);
            if (all(greaterThanEqual(tap, ivec2(0))) && all(lessThan(tap, size)))
                sum += texelFetch(u_kernels, entry, 0).rgb * texelFetch(u_illumination, tap, 0).r;
            entry = kernels_next_texel(entry, width);
        }
    }
    f_local = vec4(sum, 1.0);
}
