// lpv propagation, one step per pass over the flattened grid (drawn with fullscreen.vert): each
// cell with medium gathers its six neighbours' intensities, each scattered ((1 - s) + s g^l per
// band) and attenuated by its root, through the propagation matrices, then attenuates by its own
// root (a_{d<-s} = sqrt(a_s a_d)); pipeline/lpv_propagate.py is the numpy reference.
#include "lpv_grid.glsl"

uniform sampler2D u_red;       // SH coefficients (c00, c1-1, c10, c11) per channel
uniform sampler2D u_green;
uniform sampler2D u_blue;
uniform mat4 u_matrices[6];    // c_d += M[k] c_s for s = d - directions[k]
uniform ivec3 u_directions[6];
layout(location = 0) out vec4 f_red;
layout(location = 1) out vec4 f_green;
layout(location = 2) out vec4 f_blue;

void main() {
    ivec2 texel = ivec2(gl_FragCoord.xy);
    ivec3 cell = ivec3(texel.x, texel.y % u_grid.y, texel.y / u_grid.y);
    vec3 scatter, root;
    lpv_transport(cell, scatter, root);
    vec4 red = vec4(0.0), green = vec4(0.0), blue = vec4(0.0);
    if (root != vec3(0.0)) {
        for (int k = 0; k < 6; ++k) {
            ivec3 source = cell - u_directions[k];
            if (!lpv_inside(source)) continue;
            vec3 s_scatter, s_root;
            lpv_transport(source, s_scatter, s_root);
            ivec2 at = lpv_texel(source);
            vec3 band1 = (1.0 - s_scatter) + s_scatter * texelFetch(u_phase, at, 0).rgb;
            red += u_matrices[k] * (s_root.r * vec4(1.0, vec3(band1.r)) * texelFetch(u_red, at, 0));
            green += u_matrices[k] * (s_root.g * vec4(1.0, vec3(band1.g)) * texelFetch(u_green, at, 0));
            blue += u_matrices[k] * (s_root.b * vec4(1.0, vec3(band1.b)) * texelFetch(u_blue, at, 0));
        }
    }
    f_red = root.r * red;
    f_green = root.g * green;
    f_blue = root.b * blue;
}
