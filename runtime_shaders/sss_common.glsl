// Shared lighting terms of the sssbake runtimes.
const float SSS_PI = 3.14159265358979;

// v / |v|, or zero for a zero vector (normalize(0) is NaN on most GPUs).
vec3 sss_normalize(vec3 v) {
    float len = length(v);
    return len > 0.0 ? v / len : vec3(0.0);
}

// Exact unpolarised Fresnel transmittance into a dielectric of relative index eta
// (pipeline/fresnel.py fresnel_transmittance).
float fresnel_transmittance(float eta, float cos_i) {
    float ci = clamp(cos_i, 0.0, 1.0);
    if (ci <= 0.0) return 0.0;
    float ct = sqrt(clamp(1.0 - (1.0 - ci * ci) / (eta * eta), 0.0, 1.0));
    float rs = (ci - eta * ct) / (ci + eta * ct);
    float rp = (eta * ci - ct) / (eta * ci + ct);
    return clamp(1.0 - 0.5 * (rs * rs + rp * rp), 0.0, 1.0);
}

// Schlick's approximation of the same (pipeline/fresnel.py schlick_transmittance).
float schlick_transmittance(float eta, float cos_i) {
    float f0 = (eta - 1.0) / (eta + 1.0);
    f0 *= f0;
    return 1.0 - (f0 + (1.0 - f0) * pow(1.0 - clamp(cos_i, 0.0, 1.0), 5.0));
}

// Specular reflection off the dielectric surface: Blinn-Phong lobe (normalised) times the Fresnel
// reflectance 1 - F_t at the half vector; per unit irradiance. n, v, l unit or zero.
float surface_specular(vec3 n, vec3 v, vec3 l, float eta, float shininess) {
    vec3 h = sss_normalize(v + l);
    float ndl = max(dot(n, l), 0.0);
    float lobe = (shininess + 8.0) / (8.0 * SSS_PI) * pow(max(dot(n, h), 0.0), shininess);
    return (1.0 - fresnel_transmittance(eta, dot(h, l))) * lobe * ndl;
}

// Lambertian reflection per unit irradiance and unit albedo.
float surface_diffuse(vec3 n, vec3 l) {
    return max(dot(n, l), 0.0) / SSS_PI;
}

// The surface's own reflection in the final passes: the specular lobe
// (weight `specular`) plus a Lambertian term of albedo `diffuse`, times the irradiance.
vec3 surface_reflection(vec3 n, vec3 v, vec3 l, float irradiance, float eta, float specular, float shininess,
                        vec3 diffuse) {
    return irradiance * (specular * surface_specular(n, v, l, eta, shininess) + diffuse * surface_diffuse(n, l));
}

// Unit direction towards the light and the irradiance it delivers (normal incidence) at world
// point p. Directional (point == 0): `light` is the unit direction towards it. Point: its world
// position, irradiance falling as intensity / d^2 with d in mm (d >= 1 um: a light on the surface
// stays finite).
vec3 sss_light(int point, vec3 light, float intensity, float mm_per_unit, vec3 p, out float irradiance) {
    vec3 to_light = point == 1 ? light - p : light;
    float d_mm = max(length(to_light) * mm_per_unit, 1e-3);
    irradiance = point == 1 ? intensity / (d_mm * d_mm) : intensity;
    return sss_normalize(to_light);
}
