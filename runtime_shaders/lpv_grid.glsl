// The lpv technique's grid (Børlum et al. 2011) as the runtime passes read it: nx x ny x nz cells
// flattened into a 2-D texture nx wide and ny nz tall, cell (i, j, k) at texel (i, j + ny k), so
// fragment passes can write every cell (pipeline/lpv_runtime.py).
uniform ivec3 u_grid;          // nx, ny, nz
uniform sampler2D u_medium;    // rgb: reduced extinction σ'_t (1/mm); a: occupancy (0: no medium)
uniform sampler2D u_albedo;    // rgb: reduced albedo α'
uniform sampler2D u_phase;     // rgb: asymmetry g
uniform float u_cell_mm;

ivec2 lpv_texel(ivec3 cell) {
    return ivec2(cell.x, cell.y + u_grid.y * cell.z);
}

bool lpv_inside(ivec3 cell) {
    return all(greaterThanEqual(cell, ivec3(0))) && all(lessThan(cell, u_grid));
}

// Per channel, the share of light scattered within a cell, s = 1 - e^(-σ'_s Δx), and the square
// root of the attenuation per step, a = 3 / (2 + cosh(σ_tr Δx)): a lattice walk that keeps a per
// step decays as e^(-σ_tr r) (pipeline/lpv_propagate.py transport_factors); 0 without medium.
void lpv_transport(ivec3 cell, out vec3 scatter, out vec3 root) {
    vec4 medium = texelFetch(u_medium, lpv_texel(cell), 0);
    vec3 albedo = texelFetch(u_albedo, lpv_texel(cell), 0).rgb;
    scatter = 1.0 - exp(-albedo * medium.rgb * u_cell_mm);
    vec3 decay = min(medium.rgb * sqrt(3.0 * max(1.0 - albedo, 0.0)) * u_cell_mm, vec3(80.0));
    root = medium.a > 0.0 ? sqrt(3.0 / (2.0 + cosh(decay))) : vec3(0.0);
}
