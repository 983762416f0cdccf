// lpv accumulation (drawn with fullscreen.vert): the accumulation grid plus this step's
// propagation grid (or the injected lobes, before the first step), per channel.

uniform sampler2D u_sum_red;
uniform sampler2D u_sum_green;
uniform sampler2D u_sum_blue;
uniform sampler2D u_red;
uniform sampler2D u_green;
uniform sampler2D u_blue;
layout(location = 0) out vec4 f_red;
layout(location = 1) out vec4 f_green;
layout(location = 2) out vec4 f_blue;

void main() {
    ivec2 texel = ivec2(gl_FragCoord.xy);
    f_red = texelFetch(u_sum_red, texel, 0) + texelFetch(u_red, texel, 0);
    f_green = texelFetch(u_sum_green, texel, 0) + texelFetch(u_green, texel, 0);
    f_blue = texelFetch(u_sum_blue, texel, 0) + texelFetch(u_blue, texel, 0);
}
