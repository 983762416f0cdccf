// One triangle over the whole viewport (no attributes): per-texel passes (the kernels runtime's
// filter and gathers, the screen runtime's gather), each fragment one texel of the target
// (gl_FragCoord.xy = texel + 0.5).
void main() {
    vec2 corner = vec2(float(gl_VertexID & 1), float(gl_VertexID >> 1));
    gl_Position = vec4(corner * 4.0 - 1.0, 0.0, 1.0);
}
