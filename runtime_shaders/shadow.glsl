// Shadow-map lookup shared by the runtimes that light the surface themselves (kernels, screen).
uniform mat4 u_light_view_projection;  // world -> the shadow map's clip space
uniform sampler2D u_shadow;            // depth from the light, compare mode off
uniform float u_shadow_offset;         // world distance a lookup moves off the surface

// 1 where the light reaches p, 0 where the shadow map holds something nearer; points outside
// the light's frustum (a point light inside the bounding sphere) count as lit.
float shadow_visibility(vec3 p) {
    vec4 clip = u_light_view_projection * vec4(p, 1.0);
    if (clip.w <= 0.0) return 1.0;
    vec3 ndc = clip.xyz / clip.w;
    if (any(greaterThan(abs(ndc), vec3(1.0)))) return 1.0;
    vec3 s = 0.5 * ndc + 0.5;
    return s.z <= texture(u_shadow, s.xy).r ? 1.0 : 0.0;
}

// Visibility of the light l from surface point p of normal n, looked up off the surface along n
// and towards the light so that a lit surface does not shadow itself; 0 facing away.
float surface_visibility(vec3 p, vec3 n, vec3 l) {
    return dot(n, l) > 0.0 ? shadow_visibility(p + u_shadow_offset * (n + l)) : 0.0;
}
