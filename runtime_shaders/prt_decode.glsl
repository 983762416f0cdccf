// Decoding of the prt data (Hao & Varshney 2004) exactly as pipeline/prt_data.py states it:
//   q_c(w) = sum_k w_k T_c[r_k](w) + sum_i dq_c,i y_i(w)
// (shared tables: T_c[r] includes the point's detail term, SH evaluated at w itself)
// Tables are 2-D textures holding a linear index i at texel (i % width, i / width)
// (pipeline/prt_runtime.py `upload` makes them). Define PRT_COMPACT for data with 8-bit weight
// codes (pipeline/prt_layout.py; the attribute is the same float VEC3 for both).
#include "sh_basis.glsl"

in vec3 in_prt_ref;   // _SSS_PRT_REF: reference triangle, weight codes of w0, w1 (integers, float32)
#ifdef PRT_COMPACT
const float PRT_WEIGHT_MAX = 127.0;
#else
const float PRT_WEIGHT_MAX = 32767.0;
#endif

uniform int u_prt_k;                 // directions K
uniform int u_prt_refs;              // reference points R (0: none)
uniform int u_prt_ref_channels;      // 3: RGB tables; 1: one shape per point (levels per channel) times its colour
// SH order of dq (0: none). Defining PRT_SH_ORDER compiles a variant for one order: constant
// loop bounds let the compiler unroll the SH terms and keep them in registers (~25 % faster here).
#ifdef PRT_SH_ORDER
const int prt_order = PRT_SH_ORDER;
#else
uniform int u_prt_order;
#define prt_order u_prt_order
#endif
uniform float u_prt_weight_scale;
uniform int u_prt_lookup_size;
uniform float u_prt_dq_scale[3 * SH_MAX_ORDER * SH_MAX_ORDER];  // [c * C + i]

// SH order of the reference points' detail terms (0: none); PRT_DETAIL_ORDER compiles a variant
// for one order, as PRT_SH_ORDER does.
#ifdef PRT_DETAIL_ORDER
const int prt_detail_order = PRT_DETAIL_ORDER;
#else
uniform int u_prt_detail_order;
#define prt_detail_order u_prt_detail_order
#endif
uniform float u_prt_detail_scale[SH_MAX_ORDER * SH_MAX_ORDER];
// RGBA8I: point r's 3 colour codes, then its D² SH codes, four per texel from texel
// r * ceil((D² + 3) / 4) on (fewer fetches than one code per texel)
uniform isampler2D u_prt_detail;

uniform usampler2D u_prt_ref_codes;   // RGBA8UI / R8UI: (r * K + a) -> codes of the 3 channels / the shape
uniform sampler2D u_prt_ref_scale;    // RGBA32F: r -> colour of point r's shape (shared tables)
uniform isampler2D u_prt_ref_tris;    // RGBA32I: triangle -> its 3 reference points
uniform sampler2D u_prt_lut;          // RGBA32F 256 x 1: level -> RGB value
uniform isampler2D u_prt_dir_tris;    // RGBA32I: hull triangle -> its 3 directions
uniform isampler2D u_prt_dir_neigh;   // RGBA32I: hull triangle -> neighbour opposite each corner
uniform sampler2D u_prt_dir_inv;      // RGBA32F: (3 t + row) -> row of the inverse matrix
uniform isampler2D u_prt_dir_lookup;  // R32I L x L
uniform isampler2D u_prt_dq;          // R32I: (vertex * 3C + c * C + i) -> code in [-127, 127]

const int PRT_WALK_STEPS = 6;         // pipeline/directions.py WALK_STEPS

// (index % width, index / width) without integer division, which GPUs and CPU rasterisers
// emulate slowly: the float quotient is off by at most one while rows stay below 2^20 (texture
// limits keep them below 2^15), and one correction step fixes it.
ivec2 prt_texel(int index, int width) {
    int row = int(float(index) / float(width));
    int col = index - row * width;
    row += col >= width ? 1 : (col < 0 ? -1 : 0);
    col += col >= width ? -width : (col < 0 ? width : 0);
    return ivec2(col, row);
}

ivec4 prt_fetch_i(isampler2D s, int index) { return texelFetch(s, prt_texel(index, textureSize(s, 0).x), 0); }
uvec4 prt_fetch_u(usampler2D s, int index) { return texelFetch(s, prt_texel(index, textureSize(s, 0).x), 0); }
vec4 prt_fetch_f(sampler2D s, int index) { return texelFetch(s, prt_texel(index, textureSize(s, 0).x), 0); }

// Octahedral map of pipeline/prt_data.py; a zero w lands on the centre texel instead of NaN.
ivec2 prt_octahedral_texel(vec3 w, int size) {
    vec2 p = w.xy / max(abs(w.x) + abs(w.y) + abs(w.z), 1e-30);
    if (w.z < 0.0) {
        vec2 s = vec2(p.x >= 0.0 ? 1.0 : -1.0, p.y >= 0.0 ? 1.0 : -1.0);
        p = (1.0 - abs(p.yx)) * s;
    }
    return clamp(ivec2(floor((p * 0.5 + 0.5) * float(size))), ivec2(0), ivec2(size - 1));
}

vec3 prt_barycentric(int t, vec3 w) {
    // the three rows of triangle t's inverse are consecutive texels
    ivec2 width = ivec2(textureSize(u_prt_dir_inv, 0).x, 0);
    ivec2 texel = prt_texel(3 * t, width.x);
    vec3 b;
    for (int row = 0; row < 3; ++row) {
        b[row] = dot(texelFetch(u_prt_dir_inv, texel, 0).xyz, w);
        texel = texel.x + 1 == width.x ? ivec2(0, texel.y + 1) : texel + ivec2(1, 0);
    }
    return b;
}

// The hull triangle containing w and its clamped, normalised barycentrics (directions.lookup_weights).
void prt_direction_weights(vec3 w, out ivec3 dirs, out vec3 beta) {
    int t = texelFetch(u_prt_dir_lookup, prt_octahedral_texel(w, u_prt_lookup_size), 0).x;
    vec3 b = prt_barycentric(t, w);
    for (int step = 0; step < PRT_WALK_STEPS; ++step) {
        int worst = (b.x <= b.y && b.x <= b.z) ? 0 : (b.y <= b.z ? 1 : 2);
        if (b[worst] >= 0.0) break;
        t = prt_fetch_i(u_prt_dir_neigh, t)[worst];
        b = prt_barycentric(t, w);
    }
    beta = max(b, vec3(0.0));
    float total = beta.x + beta.y + beta.z;
    beta = total > 0.0 ? beta / total : vec3(1.0 / 3.0);
    dirs = prt_fetch_i(u_prt_dir_tris, t).xyz;
}

// This vertex's reference triangle and weight codes, from its attributes.
void prt_vertex_reference(out int triangle, out vec2 codes) {
    triangle = int(in_prt_ref.x);  // exact: float32 holds integers below 2^24
    codes = in_prt_ref.yz;
}

// Scattered radiance per unit irradiance (RGB) of the current vertex, number `vertex`, lit from
// unit direction w.
vec3 prt_decode(int vertex, vec3 w) {
    vec3 q = vec3(0.0);
    if (u_prt_refs > 0) {
        ivec3 dirs;
        vec3 beta;
        prt_direction_weights(w, dirs, beta);
        int triangle;
        vec2 codes;
        prt_vertex_reference(triangle, codes);
        vec2 w01 = codes / PRT_WEIGHT_MAX * u_prt_weight_scale;
        vec3 weights = vec3(w01, 1.0 - w01.x - w01.y);
        ivec3 refs = prt_fetch_i(u_prt_ref_tris, triangle).xyz;
        float yd[SH_MAX_ORDER * SH_MAX_ORDER];
        int detail = prt_detail_order * prt_detail_order;
        if (detail > 0) {
            sh_basis(w, prt_detail_order, yd);
            for (int i = 0; i < detail; ++i) yd[i] *= u_prt_detail_scale[i] / 127.0;
        }
        for (int k = 0; k < 3; ++k) {
            vec3 table = vec3(0.0);
            // the LUT is one row of 256 texels
            if (u_prt_ref_channels == 1) {  // one code, a level per channel
                for (int a = 0; a < 3; ++a) {
                    int code = int(prt_fetch_u(u_prt_ref_codes, refs[k] * u_prt_k + dirs[a]).r);
                    table += beta[a] * texelFetch(u_prt_lut, ivec2(code, 0), 0).rgb;
                }
                table *= prt_fetch_f(u_prt_ref_scale, refs[k]).rgb;
                if (detail > 0) {
                    int width = textureSize(u_prt_detail, 0).x;
                    int texels = (detail + 6) / 4;
                    ivec2 texel = prt_texel(refs[k] * texels, width);
                    vec4 first = vec4(texelFetch(u_prt_detail, texel, 0));
                    float shape = first.w * yd[0];
                    for (int t = 1; t < texels; ++t) {
                        texel = texel.x + 1 == width ? ivec2(0, texel.y + 1) : texel + ivec2(1, 0);
                        vec4 code = vec4(texelFetch(u_prt_detail, texel, 0));
                        for (int j = 0; j < 4; ++j) {
                            int i = 4 * t + j - 3;
                            if (i < detail) shape += code[j] * yd[i];
                        }
                    }
                    table += first.xyz / 127.0 * shape;
                }
            } else {
                for (int a = 0; a < 3; ++a) {
                    ivec3 code = ivec3(prt_fetch_u(u_prt_ref_codes, refs[k] * u_prt_k + dirs[a]).rgb);
                    table += beta[a] * vec3(texelFetch(u_prt_lut, ivec2(code.r, 0), 0).r,
                                            texelFetch(u_prt_lut, ivec2(code.g, 0), 0).g,
                                            texelFetch(u_prt_lut, ivec2(code.b, 0), 0).b);
                }
            }
            q += weights[k] * table;
        }
    }
    if (prt_order > 0) {
        float y[SH_MAX_ORDER * SH_MAX_ORDER];
        sh_basis(w, prt_order, y);
        int count = prt_order * prt_order;
        // a vertex's 3C codes are consecutive: walk the texels instead of mapping each index
        int width = textureSize(u_prt_dq, 0).x;
        ivec2 texel = prt_texel(vertex * 3 * count, width);
        for (int c = 0; c < 3; ++c) {
            float sum = 0.0;
            for (int i = 0; i < count; ++i) {
                float code = float(texelFetch(u_prt_dq, texel, 0).x);
                sum += code / 127.0 * u_prt_dq_scale[c * count + i] * y[i];
                texel = texel.x + 1 == width ? ivec2(0, texel.y + 1) : texel + ivec2(1, 0);
            }
            q[c] += sum;
        }
    }
    return q;
}
