/* Aperture samples (random, stratified, low-discrepancy) and aperture shapes.
 *
 * Every point is a pure function of (seed, wavelength, index): no generator state, so a
 * render is the same whatever the thread count and however run() calls are split. */
#include "render.h"

#include <math.h>

#define PI 3.14159265358979323846

/* The finaliser of splitmix64: a bijective 64-bit mix with good avalanche. */
static uint64_t mix64(uint64_t z)
{
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    return z ^ (z >> 31);
}

/* A 64-bit hash of three values (stateless random numbers). */
static uint64_t lensrt_hash3(uint64_t a, uint64_t b, uint64_t c)
{
    return mix64(mix64(mix64(a + 0x9e3779b97f4a7c15ULL) ^ b) ^ c);
}

/* A uniform double in [0, 1) from the top 53 bits. */
static double unit(uint64_t bits) { return (double)(bits >> 11) * (1.0 / 9007199254740992.0); }

/* The second dimension of the Sobol sequence (primitive polynomial x + 1): direction
 * numbers v_k = v_{k-1} ^ (v_{k-1} >> 1), starting at 2^31. */
static uint32_t sobol2(uint32_t i)
{
    uint32_t v = 1u << 31, x = 0;
    for (; i; i >>= 1, v ^= v >> 1)
        if (i & 1u) x ^= v;
    return x;
}

/* The first dimension: the base-2 radical inverse (bit reversal). */
static uint32_t reverse_bits(uint32_t x)
{
    x = (x << 16) | (x >> 16);
    x = ((x & 0x00ff00ffu) << 8) | ((x & 0xff00ff00u) >> 8);
    x = ((x & 0x0f0f0f0fu) << 4) | ((x & 0xf0f0f0f0u) >> 4);
    x = ((x & 0x33333333u) << 2) | ((x & 0xccccccccu) >> 2);
    x = ((x & 0x55555555u) << 1) | ((x & 0xaaaaaaaau) >> 1);
    return x;
}

/* Stratified samples come in blocks of STRATA cells (a 32 x 32 grid), one jittered
 * sample per cell, visited in an order whose prefixes are spread over the whole grid. */
#define STRATA_SIDE 32u
#define STRATA (STRATA_SIDE * STRATA_SIDE)

static void unit_square(lensrt_sampler sampler, uint64_t seed, int wavelength, uint64_t index,
                        double *u, double *v)
{
    uint64_t stream = lensrt_hash3(seed, (uint64_t)wavelength, 0x5a4d504c45ULL);
    uint64_t h = lensrt_hash3(stream, index, 1);
    switch (sampler) {
    case LENSRT_SAMPLER_RANDOM:
        *u = unit(h);
        *v = unit(mix64(h ^ 0x2545f4914f6cdd1dULL));
        return;
    case LENSRT_SAMPLER_STRATIFIED: {
        // Cell of the k-th sample of its block: the k-th point of the (0,2)-sequence on the
        // 32 x 32 grid (its first 1024 points hit every cell once, and every prefix of 2^m
        // points is evenly spread), digit-scrambled per block by XOR of the cell indices
        uint64_t b = lensrt_hash3(stream, index / STRATA, 2);
        uint32_t k = (uint32_t)(index % STRATA);
        uint32_t cx = (reverse_bits(k) >> 27) ^ (uint32_t)(b & 31u);
        uint32_t cy = (sobol2(k) >> 27) ^ (uint32_t)((b >> 5) & 31u);
        *u = ((double)cx + unit(h)) / STRATA_SIDE;
        *v = ((double)cy + unit(mix64(h ^ 0x2545f4914f6cdd1dULL))) / STRATA_SIDE;
        return;
    }
    case LENSRT_SAMPLER_DEFAULT:
    case LENSRT_SAMPLER_SOBOL:
    default: {
        // Sobol (0,2)-sequence with a random toroidal shift per seed and wavelength
        uint32_t i = (uint32_t)index;
        double su = unit(lensrt_hash3(stream, 0, 3)), sv = unit(lensrt_hash3(stream, 0, 4));
        *u = (double)reverse_bits(i) * (1.0 / 4294967296.0) + su;
        *v = (double)sobol2(i) * (1.0 / 4294967296.0) + sv;
        if (*u >= 1.0) *u -= 1.0;
        if (*v >= 1.0) *v -= 1.0;
        return;
    }
    }
}

double lensrt_region_measure(const lensrt_region *region)
{
    switch (region->kind) {
    case LENSRT_REGION_BOX: return 4.0 * region->rx * region->ry;
    case LENSRT_REGION_INTERVAL: return 2.0 * region->rx;
    default: return PI * region->rx * region->rx;
    }
}

void lensrt_sample_aperture(lensrt_sampler sampler, uint64_t seed, int wavelength,
                            uint64_t first, uint64_t count, const lensrt_region *region,
                            double *xy)
{
    uint64_t k;
    for (k = 0; k < count; k++) {
        double u, v, a, b, r, phi;
        unit_square(sampler, seed, wavelength, first + k, &u, &v);
        switch (region->kind) {
        case LENSRT_REGION_BOX:
            xy[2 * k] = (2.0 * u - 1.0) * region->rx;
            xy[2 * k + 1] = (2.0 * v - 1.0) * region->ry;
            break;
        case LENSRT_REGION_INTERVAL:
            xy[2 * k] = (2.0 * u - 1.0) * region->rx;
            xy[2 * k + 1] = 0.0;
            break;
        default:
            // Concentric map of the square onto the disc (keeps strata compact)
            a = 2.0 * u - 1.0;
            b = 2.0 * v - 1.0;
            if (a == 0.0 && b == 0.0) {
                r = 0.0;
                phi = 0.0;
            } else if (fabs(a) > fabs(b)) {
                r = a;
                phi = (PI / 4.0) * (b / a);
            } else {
                r = b;
                phi = PI / 2.0 - (PI / 4.0) * (a / b);
            }
            xy[2 * k] = region->rx * r * cos(phi);
            xy[2 * k + 1] = region->rx * r * sin(phi);
            break;
        }
    }
}

int lensrt_aperture_contains(const lensrt_aperture *ap, double radius_mm, double x, double y)
{
    switch (ap->shape) {
    case LENSRT_APERTURE_SLIT: {
        // One slit centred on the axis, or two at +-separation/2
        double h = 0.5 * ap->slit_width_mm, s = 0.5 * ap->slit_separation_mm;
        if (fabs(y) > radius_mm) return 0;
        if (s <= 0.0) return fabs(x) <= h;
        return fabs(x - s) <= h || fabs(x + s) <= h;
    }
    case LENSRT_APERTURE_BLADES: {
        // Regular polygon with vertices on the circle; curved blades bulge outward by a
        // sagitta of curvature * (R - apothem), reaching the circle at curvature 1
        int n = ap->blades;
        double rot = ap->rotation_deg * (PI / 180.0);
        double half = PI / n;
        double apothem = radius_mm * cos(half), chord = radius_mm * sin(half);
        double sag = ap->blade_curvature * (radius_mm - apothem);
        double phi = atan2(y, x) - rot - half;
        double k = floor(phi / (2.0 * half) + 0.5);
        double mid = rot + half + k * 2.0 * half;            // direction of this edge's normal
        double u = x * cos(mid) + y * sin(mid), v = -x * sin(mid) + y * cos(mid);
        double rho, centre;
        if (x * x + y * y > radius_mm * radius_mm) return 0;
        if (sag <= 1e-12 * radius_mm) return u <= apothem;
        rho = (chord * chord + sag * sag) / (2.0 * sag);
        centre = apothem + sag - rho;
        return (u - centre) * (u - centre) + v * v <= rho * rho;
    }
    case LENSRT_APERTURE_CIRCLE:
    default:
        return x * x + y * y <= radius_mm * radius_mm;
    }
}

const char *lensrt_sampler_name(lensrt_sampler s)
{
    return s == LENSRT_SAMPLER_RANDOM ? "random" : s == LENSRT_SAMPLER_STRATIFIED ? "stratified" : "sobol";
}
