// Tables of the kernels runtime (pipeline/kernels_runtime.py) hold entry i at texel
// (i % width, i / width); shaders get the texel of a row's first entry from the CPU and walk on, so
// they never divide.

// The texel after `texel` in a table `width` texels wide.
ivec2 kernels_next_texel(ivec2 texel, int width) {
    return texel.x + 1 == width ? ivec2(0, texel.y + 1) : texel + ivec2(1, 0);
}
