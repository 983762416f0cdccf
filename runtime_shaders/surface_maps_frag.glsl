// Fragment side of surface_maps_vert.glsl: the base-colour texture and the normal map of the glTF
// material (three.js runtime only; without the macros the albedo is 1 and the normal unchanged).
#ifdef SSS_ALBEDO_MAP
in vec2 v_albedo_uv;
uniform sampler2D u_albedo_map;  // sRGB-encoded, decoded by the sampler (three's SRGB8_ALPHA8 upload)
#endif
#ifdef SSS_NORMAL_MAP
in vec2 v_normal_uv;
uniform sampler2D u_normal_map;
uniform vec2 u_normal_scale;     // glTF normalTexture.scale, y negated by GLTFLoader for derivative frames
#endif

// The base-colour texture's linear albedo at this fragment (1 without a texture).
vec3 surface_albedo() {
#ifdef SSS_ALBEDO_MAP
    return texture(u_albedo_map, v_albedo_uv).rgb;
#else
    return vec3(1.0);
#endif
}

// Unit normal `n` (world) perturbed by the normal map, in the tangent frame built from the screen
// derivatives of world position `p` and the map's coordinates (Mikkelsen 2010's per-pixel frame,
// three's perturbNormal2Arb, what three draws a glTF primitive without TANGENT with), so the
// runtime's modes shade with the normal the fallback's MeshPhysicalMaterial uses (sssbake writes
// single-sided materials: no flip for back faces).
vec3 surface_normal(vec3 n, vec3 p) {
#ifdef SSS_NORMAL_MAP
    vec3 q0 = dFdx(p), q1 = dFdy(p);
    vec2 st0 = dFdx(v_normal_uv), st1 = dFdy(v_normal_uv);
    vec3 q1perp = cross(q1, n), q0perp = cross(n, q0);
    vec3 t = q1perp * st0.x + q0perp * st1.x;
    vec3 b = q1perp * st0.y + q0perp * st1.y;
    float det = max(dot(t, t), dot(b, b));
    float scale = det == 0.0 ? 0.0 : inversesqrt(det);
    vec3 m = texture(u_normal_map, v_normal_uv).xyz * 2.0 - 1.0;
    m.xy *= u_normal_scale;
    return sss_normalize(mat3(t * scale, b * scale, n) * m);
#else
    return n;
#endif
}
