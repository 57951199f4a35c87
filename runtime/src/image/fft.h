/* The complex FFT of the image's convolutions (issue 38): written here, no third-party
 * code. Mixed radix (4, 2, 3, 5, and any other prime factor by a plain O(p^2) butterfly)
 * Stockham autosort passes in double precision, twiddles precomputed in a plan.
 *
 * Data are interleaved complex doubles (re, im). A transform may run over `howmany`
 * interleaved sequences at once: element t of sequence q at index q + howmany * t. The
 * columns of a row-major 2-D array are exactly that (howmany = its width), so a 2-D
 * transform is its rows one by one, then every column in one batched pass whose inner
 * loop walks along the rows (contiguous, vectorisable).
 *
 * The forward transform is X_k = sum_t x_t exp(-2 pi i t k / n); the inverse has the
 * opposite sign and is not scaled (divide by n yourself). A plan is read-only once made:
 * any number of threads may use one at once, each with its own work buffer. */
#ifndef LENSRT_IMAGE_FFT_H
#define LENSRT_IMAGE_FFT_H

#include "lensrt.h"

#include <stddef.h>

#define IMAGE_FFT_MAX_FACTORS 64

typedef struct image_fft_plan {
    int n;
    int n_factors;
    int factors[IMAGE_FFT_MAX_FACTORS]; /* in the order the passes use them */
    double *twiddle;                    /* n complex: exp(-2 pi i t / n), t = 0 .. n - 1 */
} image_fft_plan;

/* The smallest n' >= n of the form 2^a 3^b 5^c (n' = 1 for n <= 1; 0 above 2^30). */
int image_fft_good_size(int n);

/* A plan for length n >= 1 through the context's allocator (NULL: out of memory, n < 1). */
image_fft_plan *image_fft_plan_create(lensrt_context ctx, int n);
void image_fft_plan_destroy(lensrt_context ctx, image_fft_plan *plan);

/* Transform `howmany` interleaved sequences of plan->n in `data` (2 n howmany doubles) in
 * place; `work` holds as many doubles. inverse: 0 forward, 1 inverse (unscaled). */
void image_fft_many(const image_fft_plan *plan, double *data, double *work, size_t howmany, int inverse);

/* A 2-D transform of rows->n x cols->n (width x height) complex values, row-major, in
 * place; `work` holds 2 width height doubles. Forward: the rows below `n_rows` are zero
 * (a padded image: the rest need no row pass), then every column. Inverse: every column,
 * then only the rows first_row .. first_row + n_rows - 1 (the ones the caller reads). */
void image_fft_2d_forward(const image_fft_plan *rows, const image_fft_plan *cols, double *data, double *work,
                          int n_rows);
void image_fft_2d_inverse(const image_fft_plan *rows, const image_fft_plan *cols, double *data, double *work,
                          int first_row, int n_rows);

/* Products of the spectra of real planes packed two in one complex transform (nx x ny,
 * in z): with z = FFT(a + i b) and q = FFT(ka + i kb), image_fft_packed_product makes z
 * FFT(a * ka + i b * kb) (* the cyclic convolution: two products for one inverse); with
 * z = FFT(a + i ka), image_fft_packed_self_product makes z FFT(a * ka). Each uses
 * A(f) = (Z(f) + conj Z(-f)) / 2 and B(f) = (Z(f) - conj Z(-f)) / 2i, the transforms of
 * the real and imaginary parts, a pair (f, -f) at a time. */
void image_fft_packed_product(double *z, const double *q, int nx, int ny);
void image_fft_packed_self_product(double *z, int nx, int ny);

#endif
