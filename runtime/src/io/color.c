/*
 * CIE 1931 colour for lensrt: the 2-degree colour matching functions and the
 * spectrum -> linear sRGB (D65) conversion used for the RGB preview of a render.
 *
 * Colour matching functions: no vendored table. We use the analytic multi-lobe fit of
 *
 *   C. Wyman, P.-P. Sloan, P. Shirley, "Simple Analytic Approximations to the CIE XYZ
 *   Color Matching Functions", Journal of Computer Graphics Techniques (JCGT) 2(2),
 *   1-11, 2013, http://jcgt.org/published/0002/02/01/
 *
 * (the "multi-lobe" fit of the 1931 2-degree observer, their equation 2 and table 1):
 * each function is a sum of piecewise Gaussians
 *
 *   g(lambda; mu, s1, s2) = exp(-(lambda - mu)^2 / (2 s^2)),  s = s1 below mu, s2 above,
 *
 * with amplitudes, centres mu and widths s1, s2 in nanometres as published. The fit
 * is smooth and cheap, and it is close to the CIE table (a few hundredths at most near
 * the lobe peaks; test_image_io measures the residual at tabulated wavelengths).
 *
 * XYZ -> linear sRGB: the matrix of IEC 61966-2-1 (sRGB primaries, D65 white).
 */
#include "image_io.h"

#include <math.h>
#include <stddef.h>

/* One piecewise Gaussian lobe of the Wyman-Sloan-Shirley fit. */
typedef struct cmf_lobe {
    double amplitude;   /* dimensionless (CMF value at the peak of this lobe) */
    double mu_nm;       /* centre of the lobe */
    double sigma_lo_nm; /* width below the centre */
    double sigma_hi_nm; /* width above the centre */
} cmf_lobe;

/* x-bar: three lobes (one negative, around the x-bar minimum near 500 nm). */
static const cmf_lobe cmf_x_lobes[3] = {
    {1.056, 599.8, 37.9, 31.0},
    {0.362, 442.0, 16.0, 26.7},
    {-0.065, 501.1, 20.4, 26.2}};
/* y-bar: two lobes. */
static const cmf_lobe cmf_y_lobes[2] = {
    {0.821, 568.8, 46.9, 40.5},
    {0.286, 530.9, 16.3, 31.1}};
/* z-bar: two lobes. */
static const cmf_lobe cmf_z_lobes[2] = {
    {1.217, 437.0, 11.8, 36.0},
    {0.681, 459.0, 26.0, 13.8}};

/* The visible range over which an equal-energy spectrum is normalised to Y = 1 (nm). */
#define LENSRT_VISIBLE_MIN_NM 380.0
#define LENSRT_VISIBLE_MAX_NM 780.0

/* IEC 61966-2-1 XYZ -> linear sRGB (D65 white), rows R, G, B. */
static const double xyz_to_srgb[3][3] = {
    {3.2406, -1.5372, -0.4986},
    {-0.9689, 1.8758, 0.0415},
    {0.0557, -0.2040, 1.0570}};

static double lobe_value(const cmf_lobe *lobe, double lambda_nm)
{
    double sigma = lambda_nm < lobe->mu_nm ? lobe->sigma_lo_nm : lobe->sigma_hi_nm;
    double t = (lambda_nm - lobe->mu_nm) / sigma;
    return lobe->amplitude * exp(-0.5 * t * t);
}

/* Integral of one lobe over [a, b] (nm), in closed form: each half of a piecewise
 * Gaussian integrates to sigma * sqrt(pi / 2) * erf(...). */
static double lobe_integral(const cmf_lobe *lobe, double a_nm, double b_nm)
{
    const double sqrt_half_pi = 1.2533141373155002512; /* sqrt(pi / 2) */
    const double inv_sqrt2 = 0.70710678118654752440;   /* 1 / sqrt(2) */
    double sum = 0.0;
    /* Part below the centre: [a, min(b, mu)] with the lower width. */
    if (a_nm < lobe->mu_nm) {
        double hi = b_nm < lobe->mu_nm ? b_nm : lobe->mu_nm;
        double s = lobe->sigma_lo_nm;
        sum += s * sqrt_half_pi *
               (erf((hi - lobe->mu_nm) * inv_sqrt2 / s) - erf((a_nm - lobe->mu_nm) * inv_sqrt2 / s));
    }
    /* Part above the centre: [max(a, mu), b] with the upper width. */
    if (b_nm > lobe->mu_nm) {
        double lo = a_nm > lobe->mu_nm ? a_nm : lobe->mu_nm;
        double s = lobe->sigma_hi_nm;
        sum += s * sqrt_half_pi *
               (erf((b_nm - lobe->mu_nm) * inv_sqrt2 / s) - erf((lo - lobe->mu_nm) * inv_sqrt2 / s));
    }
    return lobe->amplitude * sum;
}

void lensrt_cie1931_xyz(double wavelength_nm, double xyz[3])
{
    size_t i;
    if (!xyz)
        return;
    xyz[0] = xyz[1] = xyz[2] = 0.0;
    for (i = 0; i < sizeof cmf_x_lobes / sizeof cmf_x_lobes[0]; ++i)
        xyz[0] += lobe_value(&cmf_x_lobes[i], wavelength_nm);
    for (i = 0; i < sizeof cmf_y_lobes / sizeof cmf_y_lobes[0]; ++i)
        xyz[1] += lobe_value(&cmf_y_lobes[i], wavelength_nm);
    for (i = 0; i < sizeof cmf_z_lobes / sizeof cmf_z_lobes[0]; ++i)
        xyz[2] += lobe_value(&cmf_z_lobes[i], wavelength_nm);
}

/* Integral of y-bar over the visible range (nm), about 106.9 for this fit. */
static double ybar_visible_integral(void)
{
    double sum = 0.0;
    size_t i;
    for (i = 0; i < sizeof cmf_y_lobes / sizeof cmf_y_lobes[0]; ++i)
        sum += lobe_integral(&cmf_y_lobes[i], LENSRT_VISIBLE_MIN_NM, LENSRT_VISIBLE_MAX_NM);
    return sum;
}

/* The midpoint-rule width of wavelength w (nm). The cell of a sample reaches halfway to
 * its neighbours in wavelength order (the input may be in any order); at either end
 * the cell is symmetric about the sample, so n uniform samples at bin centres over
 * 380-780 nm get 400 / n nm each (25 nm for 16). Equal wavelengths share one cell. A
 * single distinct wavelength gets the whole visible range (400 nm, the n = 1 case of
 * the same rule). O(n) per wavelength, no allocation: this function cannot fail. */
static double midpoint_width_nm(int n, const double *wl, int w)
{
    double lambda = wl[w];
    double below = -HUGE_VAL, above = HUGE_VAL, width;
    int i, same = 0, has_below = 0, has_above = 0;
    for (i = 0; i < n; ++i) {
        double l = wl[i];
        if (l == lambda)
            ++same;
        else if (l < lambda && l > below) {
            below = l;
            has_below = 1;
        } else if (l > lambda && l < above) {
            above = l;
            has_above = 1;
        }
    }
    if (has_below && has_above)
        width = 0.5 * (above - below);
    else if (has_above)
        width = above - lambda;
    else if (has_below)
        width = lambda - below;
    else
        width = LENSRT_VISIBLE_MAX_NM - LENSRT_VISIBLE_MIN_NM;
    return width / (double)same;
}

void lensrt_spectrum_to_rgb(int n_wavelengths, const double *wavelengths_nm,
                            const float *spectral, size_t n_pixels, float *rgb)
{
    double inv_norm;
    size_t p;
    int w;
    if (!rgb)
        return;
    /* Start from black; a spectrum with no samples stays black. */
    for (p = 0; p < 3 * n_pixels; ++p)
        rgb[p] = 0.0f;
    if (n_wavelengths < 1 || !wavelengths_nm || !spectral)
        return;

    /* Normalisation: an equal-energy spectrum of value 1 at every wavelength over
     * 380-780 nm has Y = integral of y-bar over 380-780 nm; dividing by that integral
     * (in closed form for the fit) makes its Y = 1. A sampled spectrum then gets Y = 1
     * up to the error of the midpoint rule. */
    inv_norm = 1.0 / ybar_visible_integral();

    /* Accumulate wavelength by wavelength (the spectral image is stored one plane per
     * wavelength, so this walks memory in order): fold the colour matching functions,
     * the cell width and the XYZ -> sRGB matrix into three weights per wavelength. */
    for (w = 0; w < n_wavelengths; ++w) {
        const float *plane = spectral + (size_t)w * n_pixels;
        double xyz[3], weight[3], d_lambda;
        int c;
        lensrt_cie1931_xyz(wavelengths_nm[w], xyz);
        d_lambda = midpoint_width_nm(n_wavelengths, wavelengths_nm, w) * inv_norm;
        for (c = 0; c < 3; ++c)
            weight[c] = (xyz_to_srgb[c][0] * xyz[0] + xyz_to_srgb[c][1] * xyz[1] +
                         xyz_to_srgb[c][2] * xyz[2]) * d_lambda;
        for (p = 0; p < n_pixels; ++p) {
            double s = (double)plane[p];
            float *out = rgb + 3 * p;
            out[0] = (float)((double)out[0] + s * weight[0]);
            out[1] = (float)((double)out[1] + s * weight[1]);
            out[2] = (float)((double)out[2] + s * weight[2]);
        }
    }
}
