// lpv injection, second pass: the point's lobe, summed per cell by additive blending.
in vec4 v_lobe;
out vec4 f_lobe;

void main() {
    f_lobe = v_lobe;
}
