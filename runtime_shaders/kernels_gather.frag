// A sparse matrix times a vector as a gather pass (no compute shaders): per output texel, i.e.
// per welded vertex, the sum over its CSR row's entries p of weights[p] * source[entries[p]][u_channel].
// Distribution (pipeline/kernels_data.py step 3): the row lists the vertex's (texel, corner)
// pairs, weights (direct RGB, dual), source E: out (B_d, E_g). Global response (step 4): the row
// is F's row, weights F RGB (an RGB texture reads alpha 1), source E_g: out rgb B_g (alpha, the
// sum of the row's E_g, is not used).
#include "kernels_tables.glsl"

uniform isampler2D u_rows;     // RGBA32I per vertex: texel of the row's first entry (xy), entry count (z)
uniform isampler2D u_entries;  // RG32I: texel in u_source of each entry's source
uniform sampler2D u_weights;   // each entry's weights, laid out as u_entries
uniform sampler2D u_source;
uniform int u_channel;         // channel of u_source to read
out vec4 f_sum;

void main() {
    ivec4 row = texelFetch(u_rows, ivec2(gl_FragCoord.xy), 0);
    int width = textureSize(u_weights, 0).x;
    ivec2 entry = row.xy;
    vec4 sum = vec4(0.0);
    for (int p = 0; p < row.z; ++p) {
        float source = texelFetch(u_source, texelFetch(u_entries, entry, 0).xy, 0)[u_channel];
        sum += texelFetch(u_weights, entry, 0) * source;
        entry = kernels_next_texel(entry, width);
    }
    f_sum = sum;
}
