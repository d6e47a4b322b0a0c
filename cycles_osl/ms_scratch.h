// Material Structures: the scratch term of thesis ch. 4 (mirrors core/scratch/scratch_radiance.py).
//
// Units: positions, widths, depths, sigma in micrometres; wavelengths in micrometres inside these
// functions. Directions in the local frame (t_u, t_v, n) of the scratch plane. Each function names
// the core function it ports.

#define MS_PI 3.14159265358979
#define MS_SQRT_PI 1.7724538509055159
#define MS_REACH_SIGMAS 3.5  // scratch_set.REACH_SIGMAS
#define MS_GAUSS_CUTOFF 2.5  // scratch_footprint.GAUSS_CUTOFF

// Si(x): power series for |x| < 4, complex continued fraction (E1(ix), Lentz) up to 12, asymptotic beyond.
// Float accuracy
// (~1e-6 absolute); the core's "series" form is accurate to 2e-6 (sine_integral.py).
float ms_si(float x)
{
    float ax = abs(x);
    float r = 0.0;
    if (ax < 4.0) {
        float x2 = ax * ax;
        float term = ax;  // x^(2n+1) / (2n+1)! * (-1)^n
        for (int n = 0; n < 12; ++n) {
            r += term / float(2 * n + 1);
            term *= -x2 / float((2 * n + 2) * (2 * n + 3));
        }
    } else if (ax > 12.0) {
        // asymptotic expansion, 6 terms of f and g (sine_integral.sine_integral_series), |err| < 2e-6
        float y = 1.0 / (ax * ax);
        float f = 1.0 + y * (-2.0 + y * (24.0 + y * (-720.0 + y * (40320.0 + y * -3628800.0))));
        float g = 1.0 + y * (-6.0 + y * (120.0 + y * (-5040.0 + y * (362880.0 + y * -39916800.0))));
        r = 0.5 * MS_PI - f / ax * cos(ax) - g * y * sin(ax);
    } else {
        // b = 1 + i t, c = 1 / tiny, d = h = 1 / b
        float br = 1.0, bi = ax;
        float cr = 1e30, ci = 0.0;
        float den = br * br + bi * bi;
        float dr = br / den, di = -bi / den;
        float hr = dr, hi = di;
        for (int i = 2; i < 200; ++i) {
            float a = -float((i - 1) * (i - 1));
            br += 2.0;
            // d = 1 / (a d + b)
            float er = a * dr + br, ei = a * di + bi;
            den = er * er + ei * ei;
            dr = er / den;
            di = -ei / den;
            // c = b + a / c
            den = cr * cr + ci * ci;
            cr = br + a * cr / den;
            ci = bi - a * ci / den;
            // del = c d; h *= del
            float delr = cr * dr - ci * di, deli = cr * di + ci * dr;
            float nhr = hr * delr - hi * deli, nhi = hr * deli + hi * delr;
            hr = nhr;
            hi = nhi;
            if (abs(delr - 1.0) + abs(deli) < 3e-7)
                break;
        }
        // h = (cos t - i sin t) h; Si = pi/2 + Im(h)
        float c = cos(ax), s = sin(ax);
        r = 0.5 * MS_PI + (c * hi - s * hr);
    }
    return x < 0.0 ? -r : r;
}

// int_0^zeta sinc^2(kW x / 2) dx (light_integration.sinc2_antiderivative)
float ms_sinc2_antiderivative(float zeta, float kw)
{
    float u = kw * zeta;
    float h = 0.5 * u;
    float sn = abs(h) < 1e-6 ? 1.0 : sin(h) / h;
    return 2.0 * ms_si(u) / kw - zeta * sn * sn;
}

// N(zeta1) - N(zeta0), eq. 4.27 (light_integration.band_limited_integral). Both ends in one loop: OSL
// inlines every call, and one copy of ms_si (not two) keeps the shader's per-render compile short.
float ms_band_integral(float z0, float z1, float w, float lam, float sigma)
{
    float k = 2.0 * MS_PI / lam;
    float kw = k * w;
    float nz[2];
    for (int e = 0; e < 2; ++e)
        nz[e] = ms_sinc2_antiderivative(e == 0 ? z1 : z0, kw);
    return MS_SQRT_PI / (sigma * k) * (nz[0] - nz[1]);
}

// xi2 intervals of the line xi1 = 0 inside a sphere light (light_integration.specular_line_intervals_sphere).
// Per segment: c = -wo . t, s = sqrt(1 - c^2), o2 = wo x t; per lamp (computed once per shading point):
// the unit direction p to its centre and cos_a of its angular radius. Intervals -> za[base..],
// zb[base..] (za < zb); returns their number (0..2).
int ms_sphere_intervals(float tx, float ty, float c, float s, float o2, vector p, float cos_a,
                        output float za[136], output float zb[136], int base)
{
    float pt = p[0] * tx + p[1] * ty;
    float pb = -p[0] * ty + p[1] * tx;
    float rho = hypot(pb, p[2]);
    float den = s * rho;
    if (den <= 1e-30)
        return 0;
    float q = (cos_a - c * pt) / den;
    if (q > 1.0)
        return 0;
    float phi_c = atan2(p[2], pb);
    float delta = acos(clamp(q, -1.0, 1.0));
    float lo = phi_c - delta, hi = phi_c + delta;
    int n = 0;
    for (int k = 0; k < 2; ++k) {
        float off = k == 0 ? 0.0 : 2.0 * MS_PI;
        float pa = max(lo + off, 0.0), pbb = min(hi + off, MS_PI);
        if (pbb > pa) {
            zb[base + n] = s * cos(pa) + o2;
            za[base + n] = s * cos(pbb) + o2;
            n += 1;
        }
    }
    return n;
}

// Roots in (0, pi) of A cos(phi) + B sin(phi) = C (light_integration._circle_roots), appended to br[].
int ms_circle_roots(float A, float B, float C, output float br[34], int nb)
{
    int n = nb;
    float R = hypot(A, B);
    if (R <= 1e-30)
        return n;
    float q = C / R;
    if (abs(q) > 1.0)
        return n;
    float phi0 = atan2(B, A);
    float delta = acos(q);
    for (int k = 0; k < 2; ++k) {
        float r = k == 0 ? phi0 - delta : phi0 + delta;
        r = r + MS_PI;
        r = r - 2.0 * MS_PI * floor(r / (2.0 * MS_PI));
        r -= MS_PI;
        if (r > 0.0 && r < MS_PI && n < 34) {
            br[n] = r;
            n += 1;
        }
    }
    return n;
}

// xi2 intervals inside a convex polygon light (light_integration.specular_line_intervals_polygon).
// The polygon is given by its edge great-circle normals ne[base .. base + nv) (cross products of
// consecutive unit vertex directions, computed once per shading point) and its orientation sign.
// c, s, o2: the segment's line frame (ms_sphere_intervals). Intervals -> za[zbase..], zb[zbase..];
// returns their count.
int ms_polygon_intervals(float tx, float ty, float c, float s, float o2, vector ne[64], int base, int nv,
                         float orient, output float za[136], output float zb[136], int zbase)
{
    if (s <= 0.0)
        return 0;
    vector t = vector(tx, ty, 0.0), b = vector(-ty, tx, 0.0);
    float br[34];
    int nb = 0;
    br[nb] = 0.0;
    nb += 1;
    br[nb] = MS_PI;
    nb += 1;
    for (int e = 0; e < nv; ++e) {
        vector q = ne[base + e];
        nb = ms_circle_roots(s * dot(q, b), s * q[2], -c * dot(q, t), br, nb);
    }
    // insertion sort
    for (int i = 1; i < nb; ++i) {
        float key = br[i];
        int j = i - 1;
        while (j >= 0 && br[j] > key) {
            br[j + 1] = br[j];
            j -= 1;
        }
        br[j + 1] = key;
    }
    int n = 0;
    for (int i = 0; i + 1 < nb; ++i) {
        float pa = br[i], pbb = br[i + 1];
        if (pbb <= pa)
            continue;
        float pm = 0.5 * (pa + pbb);
        vector w = c * t + s * (cos(pm) * b + vector(0, 0, sin(pm)));
        int inside = 1;
        for (int e = 0; e < nv; ++e) {
            if (dot(w, ne[base + e]) * orient < 0.0) {
                inside = 0;
                break;
            }
        }
        if (inside) {
            zb[zbase + n] = s * cos(pa) + o2;
            za[zbase + n] = s * cos(pbb) + o2;
            n += 1;
        }
    }
    return n;
}

// Length inside the footprint ellipse of the segment shifted by o across itself (scratch_footprint._chord_length).
float ms_chord_length(float A, float B, float C, float ed, float qe, float ee, float len, float o)
{
    float Bo = B + o * ed;
    float Co = C + 2.0 * o * qe + o * o * ee;
    float disc = Bo * Bo - A * Co;
    if (disc <= 0.0)
        return 0.0;
    float sq = sqrt(disc);
    float t0 = clamp((-Bo - sq) / A, 0.0, 1.0);
    float t1 = clamp((-Bo + sq) / A, 0.0, 1.0);
    return (t1 - t0) * len;
}

// Gaussian-weighted contained length, rule "chords" with 2 x 6 Gauss-Legendre nodes
// (scratch_footprint.scratch_weighted_length). The nodes of a half lie symmetrically about its midpoint
// angle: sin and cos of mid +- half x_j come from one sincos of mid and one of half x_j by the angle
// addition formulas (4 sincos per half instead of 6 sin + 6 cos); a half of zero width adds nothing.
float ms_weighted_length(float A, float B, float C, float ed, float qe, float ee, float len, float v0, float V,
                         float s_um)
{
    float gx[3] = {0.23861918608319693, 0.6612093864662645, 0.9324695142031521};
    float gw[3] = {0.46791393457269104, 0.3607615730481386, 0.17132449237917036};
    float inv_s2 = 1.0 / (s_um * s_um);
    float th0 = asin(clamp(v0 / V, -1.0, 1.0));
    float acc = 0.0;
    for (int h = 0; h < 2; ++h) {
        float span = h == 0 ? -MS_GAUSS_CUTOFF : MS_GAUSS_CUTOFF;
        float th1 = asin(clamp((v0 + span * s_um) / V, -1.0, 1.0));
        float half = 0.5 * abs(th1 - th0);
        if (half <= 0.0)
            continue;
        float mid = 0.5 * (th1 + th0);
        float sm, cm;
        sincos(mid, sm, cm);
        for (int j = 0; j < 3; ++j) {
            float sg, cg;
            sincos(half * gx[j], sg, cg);
            float hw = half * gw[j];
            for (int e = 0; e < 2; ++e) {
                float sgn = e == 0 ? -1.0 : 1.0;
                float v = V * (sm * cg + sgn * cm * sg);
                float o = v - v0;
                float ch = ms_chord_length(A, B, C, ed, qe, ee, len, o);
                if (ch != 0.0)  // most nodes of a segment at the footprint's rim: no exp for a zero chord
                    acc += ch * exp(-(o * o) * inv_s2) * (V * (cm * cg - sgn * sm * sg)) * hw;
            }
        }
    }
    return acc / (s_um * MS_SQRT_PI);
}

float ms_sinc(float y)  // numpy's sinc: sin(pi y) / (pi y)
{
    float a = MS_PI * y;
    return abs(a) < 1e-6 ? 1.0 : sin(a) / a;
}

// |eta_P|^2 of one segment from its Gaussian-weighted contained length lw (ms_weighted_length): footprint
// rule "chords" blended towards the point sample by alpha_P
// (scratch_footprint.scratch_footprint_phase_sq with scratch_weighted_length)
float ms_phase_sq(float lw, float v0, float sigma, float alpha, float area, int on_seg)
{
    // the point-sample part only where it has weight (alpha_P < 1): no exp once alpha_P = 1
    float small = on_seg && alpha < 1.0 ? 2.0 * MS_PI * sigma * sigma * exp(-(v0 * v0) / (sigma * sigma)) : 0.0;
    return alpha * 2.0 * sigma * sigma * sigma * MS_SQRT_PI * lw * MS_PI / area + (1.0 - alpha) * small;
}
