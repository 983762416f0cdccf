// Decoding of the prt data (Hao & Varshney 2004) exactly as pipeline/prt_data.py states it:
//   q_c(w) = sum_k w_k T_c[r_k](w) + sum_i dq_c,i y_i(w)
// Tables are 2-D textures holding a linear index i at texel (i % width, i / width).
#include "sh_basis.glsl"

uniform int u_prt_k;                 // directions K
uniform int u_prt_refs;              // reference points R (0: none)
uniform int u_prt_order;             // SH order of dq (0: none)
uniform float u_prt_weight_scale;
uniform int u_prt_lookup_size;
uniform float u_prt_dq_scale[3 * SH_MAX_ORDER * SH_MAX_ORDER];  // [c * C + i]

uniform usampler2D u_prt_ref_codes;   // RGBA8UI: (r * K + a) -> codes of the 3 channels
uniform isampler2D u_prt_ref_tris;    // RGBA32I: triangle -> its 3 reference points
uniform sampler2D u_prt_lut;          // RGBA32F 256 x 1: level -> RGB value
uniform isampler2D u_prt_dir_tris;    // RGBA32I: hull triangle -> its 3 directions
uniform isampler2D u_prt_dir_neigh;   // RGBA32I: hull triangle -> neighbour opposite each corner
uniform sampler2D u_prt_dir_inv;      // RGBA32F: (3 t + row) -> row of the inverse matrix
uniform isampler2D u_prt_dir_lookup;  // R32I L x L
uniform isampler2D u_prt_dq;          // R32I: (vertex * 3C + c * C + i) -> code in [-127, 127]

const int PRT_WALK_STEPS = 6;         // pipeline/directions.py WALK_STEPS

ivec2 prt_texel(int index, ivec2 size) { return ivec2(index % size.x, index / size.x); }

ivec4 prt_fetch_i(isampler2D s, int index) { return texelFetch(s, prt_texel(index, textureSize(s, 0)), 0); }
uvec4 prt_fetch_u(usampler2D s, int index) { return texelFetch(s, prt_texel(index, textureSize(s, 0)), 0); }
vec4 prt_fetch_f(sampler2D s, int index) { return texelFetch(s, prt_texel(index, textureSize(s, 0)), 0); }

ivec2 prt_octahedral_texel(vec3 w, int size) {
    vec2 p = w.xy / (abs(w.x) + abs(w.y) + abs(w.z));
    if (w.z < 0.0) {
        vec2 s = vec2(p.x >= 0.0 ? 1.0 : -1.0, p.y >= 0.0 ? 1.0 : -1.0);
        p = (1.0 - abs(p.yx)) * s;
    }
    return clamp(ivec2(floor((p * 0.5 + 0.5) * float(size))), ivec2(0), ivec2(size - 1));
}

vec3 prt_barycentric(int t, vec3 w) {
    return vec3(dot(prt_fetch_f(u_prt_dir_inv, 3 * t).xyz, w),
                dot(prt_fetch_f(u_prt_dir_inv, 3 * t + 1).xyz, w),
                dot(prt_fetch_f(u_prt_dir_inv, 3 * t + 2).xyz, w));
}

// The hull triangle containing w and its clamped, normalised barycentrics.
void prt_direction_weights(vec3 w, out ivec3 dirs, out vec3 beta) {
    int t = texelFetch(u_prt_dir_lookup, prt_octahedral_texel(w, u_prt_lookup_size), 0).x;
    for (int step = 0; step < PRT_WALK_STEPS; ++step) {
        vec3 b = prt_barycentric(t, w);
        int worst = (b.x <= b.y && b.x <= b.z) ? 0 : (b.y <= b.z ? 1 : 2);
        if (b[worst] >= 0.0) break;
        t = prt_fetch_i(u_prt_dir_neigh, t)[worst];
    }
    beta = max(prt_barycentric(t, w), vec3(0.0));
    float total = beta.x + beta.y + beta.z;
    beta = total > 0.0 ? beta / total : vec3(1.0 / 3.0);
    dirs = prt_fetch_i(u_prt_dir_tris, t).xyz;
}

// Scattered radiance per unit irradiance (RGB) of vertex `vertex` lit from unit direction w.
vec3 prt_decode(int vertex, uvec2 ref, ivec2 weight_codes, vec3 w) {
    vec3 q = vec3(0.0);
    if (u_prt_refs > 0) {
        ivec3 dirs;
        vec3 beta;
        prt_direction_weights(w, dirs, beta);
        vec2 w01 = vec2(weight_codes) / 32767.0 * u_prt_weight_scale;
        vec3 weights = vec3(w01, 1.0 - w01.x - w01.y);
        ivec3 refs = prt_fetch_i(u_prt_ref_tris, int(ref.x) + 65536 * int(ref.y)).xyz;
        for (int k = 0; k < 3; ++k) {
            vec3 table = vec3(0.0);
            for (int a = 0; a < 3; ++a) {
                uvec3 code = prt_fetch_u(u_prt_ref_codes, refs[k] * u_prt_k + dirs[a]).rgb;
                table += beta[a] * vec3(prt_fetch_f(u_prt_lut, int(code.r)).r,
                                        prt_fetch_f(u_prt_lut, int(code.g)).g,
                                        prt_fetch_f(u_prt_lut, int(code.b)).b);
            }
            q += weights[k] * table;
        }
    }
    if (u_prt_order > 0) {
        float y[SH_MAX_ORDER * SH_MAX_ORDER];
        sh_basis(w, u_prt_order, y);
        int count = u_prt_order * u_prt_order;
        for (int c = 0; c < 3; ++c) {
            float sum = 0.0;
            for (int i = 0; i < count; ++i) {
                float code = float(prt_fetch_i(u_prt_dq, (vertex * 3 + c) * count + i).x);
                sum += code / 127.0 * u_prt_dq_scale[c * count + i] * y[i];
            }
            q[c] += sum;
        }
    }
    return q;
}
