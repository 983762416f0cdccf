// Vertex side of the glTF material's maps and the baked thickness, for the three.js runtime only
// (runtime_three/sssbake-three.js defines the macros; the moderngl renderer defines none, and then
// nothing here is compiled): each map's texture coordinates after its KHR_texture_transform
// (three's Texture.matrix), and the thickness the screen technique's transmission reads.
#ifdef SSS_ALBEDO_MAP
in vec2 in_albedo_uv;
uniform mat3 u_albedo_uv_transform;
out vec2 v_albedo_uv;
#endif
#ifdef SSS_NORMAL_MAP
in vec2 in_normal_uv;
uniform mat3 u_normal_uv_transform;
out vec2 v_normal_uv;
#endif
#ifdef SSS_TRANSMISSION
in float in_thickness;   // _THICKNESS, mm along the inward normal
out float v_thickness;
#endif

void pass_surface_maps() {
#ifdef SSS_ALBEDO_MAP
    v_albedo_uv = (u_albedo_uv_transform * vec3(in_albedo_uv, 1.0)).xy;
#endif
#ifdef SSS_NORMAL_MAP
    v_normal_uv = (u_normal_uv_transform * vec3(in_normal_uv, 1.0)).xy;
#endif
#ifdef SSS_TRANSMISSION
    v_thickness = in_thickness;
#endif
}
