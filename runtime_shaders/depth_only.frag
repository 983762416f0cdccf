// Shadow-map pass: depth only (drawn with plain.vert from the light).
void main() {
}
