// Shadow-map pass of the kernels runtime: depth only (drawn with plain.vert from the light).
void main() {
}
