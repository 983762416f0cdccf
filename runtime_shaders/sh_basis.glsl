// Real spherical harmonics, index i = l*l + l + m: the real parts of the Condon-Shortley complex
// harmonics, as pipeline/sh.py `sh_basis` computes them. Orders up to SH_MAX_ORDER.
const int SH_MAX_ORDER = 8;
const float SH_PI = 3.14159265358979;

// Basis functions of order `order` at unit direction w, into out_y[0 .. order*order - 1].
void sh_basis(vec3 w, int order, out float out_y[SH_MAX_ORDER * SH_MAX_ORDER]) {
    for (int i = 0; i < SH_MAX_ORDER * SH_MAX_ORDER; ++i) out_y[i] = 0.0;
    vec2 power = vec2(1.0, 0.0);                // (x + iy)^m
    float dfact = 1.0;                          // (2m - 1)!!
    for (int m = 0; m < order; ++m) {
        if (m > 0) dfact *= float(2 * m - 1);
        float q_prev = 0.0;
        float q = ((m % 2 == 0) ? 1.0 : -1.0) * dfact;    // Q_m^m = P_m^m / sin^m
        float ratio = 1.0;                      // (l - m)! / (l + m)! at l = m: 1 / (2m)!
        for (int j = 1; j <= 2 * m; ++j) ratio /= float(j);
        for (int l = m; l < order; ++l) {
            if (l > m) {
                float next = (float(2 * l - 1) * w.z * q - float(l + m - 1) * q_prev) / float(l - m);
                q_prev = q;
                q = next;
                ratio *= float(l - m) / float(l + m);
            }
            float k = sqrt(float(2 * l + 1) / (4.0 * SH_PI) * ratio);
            if (m == 0) {
                out_y[l * l + l] = k * q;
            } else {
                out_y[l * l + l + m] = sqrt(2.0) * k * q * power.x;
                out_y[l * l + l - m] = sqrt(2.0) * k * q * power.y;
            }
        }
        power = vec2(power.x * w.x - power.y * w.y, power.x * w.y + power.y * w.x);
    }
}
