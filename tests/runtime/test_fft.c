/* test_fft: the image's complex FFT (runtime/src/image/fft.c, compiled in; issue 38)
 * against the plain O(n^2) DFT summed in long double with exactly reduced angles.
 *
 * Every length 1 .. 64 (radices 4, 2, 3, 5 and the plain butterfly of 7, 11, 13, ...,
 * 61), forward and inverse, one sequence and 3 interleaved; 2-D transforms of several
 * sizes, with the forward's zero rows skipped and the inverse's rows picked; the good
 * sizes; the packed products (two real planes in one complex transform). Tolerance:
 * the largest error over the largest |X_k| below 1e-12. A radix-r Stockham pass adds a
 * few ulps (2^-53 = 1.1e-16) per element and there are at most log2(64) = 6 passes,
 * with each twiddle correct to an ulp: 1e-15 expected; the plain butterfly of a prime p
 * sums p terms (61 x 1.1e-16 = 7e-15). 1e-12 leaves a margin of over 100 and still
 * catches any wrong twiddle or index (errors of order 1). */
#include "image/fft.h"

#include "check.h"
#include "internal_stubs.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#define TOL 1e-12

/* A test signal: not symmetric, not periodic, of both signs. */
static double signal(size_t t, int part)
{
    return part ? cos(0.7 * (double)(t * t) + 0.3) : sin(1.3 * (double)t + 0.2) + 0.1 * (double)(t % 5);
}

/* The plain DFT of x (n complex, stride `stride` complex values) into ref (contiguous). */
static void dft(const double *x, size_t n, size_t stride, int inverse, long double *ref)
{
    const long double two_pi = 6.283185307179586476925286766559L;
    size_t k, t;
    for (k = 0; k < n; k++) {
        long double sr = 0.0L, si = 0.0L;
        for (t = 0; t < n; t++) {
            // The angle reduced exactly: (t k mod n) / n of a turn
            const long double a = (inverse ? two_pi : -two_pi) * (long double)((t * k) % n) / (long double)n;
            const long double xr = x[2 * t * stride], xi = x[2 * t * stride + 1];
            sr += xr * cosl(a) - xi * sinl(a);
            si += xr * sinl(a) + xi * cosl(a);
        }
        ref[2 * k] = sr;
        ref[2 * k + 1] = si;
    }
}

/* 1-D: lengths 1 .. 64, forward and inverse, 1 and 3 interleaved sequences. */
static void test_lengths(void)
{
    size_t n;
    double worst = 0.0;
    for (n = 1; n <= 64; n++) {
        image_fft_plan *plan = image_fft_plan_create(NULL, (int)n);
        size_t howmany, q, k;
        int inverse;
        CHECK(plan != NULL, "plan %zu", n);
        if (!plan) continue;
        for (howmany = 1; howmany <= 3; howmany += 2)
            for (inverse = 0; inverse < 2; inverse++) {
                double *x = malloc(2 * n * howmany * sizeof(double)), *y = malloc(2 * n * howmany * sizeof(double));
                double *work = malloc(2 * n * howmany * sizeof(double));
                long double *ref = malloc(2 * n * sizeof(long double));
                for (k = 0; k < n * howmany; k++) {
                    x[2 * k] = signal(k, 0);
                    x[2 * k + 1] = signal(k, 1);
                }
                memcpy(y, x, 2 * n * howmany * sizeof(double));
                image_fft_many(plan, y, work, howmany, inverse);
                for (q = 0; q < howmany; q++) {
                    long double big = 0.0L, err = 0.0L;
                    dft(x + 2 * q, n, howmany, inverse, ref);
                    for (k = 0; k < 2 * n; k++) {
                        const long double e = fabsl((long double)y[2 * q + (k / 2) * 2 * howmany + k % 2] - ref[k]);
                        err = e > err ? e : err;
                        big = fabsl(ref[k]) > big ? fabsl(ref[k]) : big;
                    }
                    CHECK(err <= TOL * big, "n %zu, %s, sequence %zu of %zu: error %Lg of %Lg", n,
                          inverse ? "inverse" : "forward", q, howmany, err, big);
                    if ((double)(err / big) > worst) worst = (double)(err / big);
                }
                free(x);
                free(y);
                free(work);
                free(ref);
            }
        image_fft_plan_destroy(NULL, plan);
    }
    printf("test_fft: lengths 1 .. 64: worst relative error %.2g\n", worst);
}

/* 2-D: w x h complex values, the forward transform with rows >= nz zero (skipped), then
 * the inverse of only rows r0 .. r0 + nr - 1, each against the plain 2-D DFT. */
static void test_2d(int w, int h, int nz, int r0, int nr)
{
    image_fft_plan *px = image_fft_plan_create(NULL, w), *py = image_fft_plan_create(NULL, h);
    const size_t n = (size_t)w * (size_t)h;
    double *x = calloc(2 * n, sizeof(double)), *y = malloc(2 * n * sizeof(double));
    double *work = malloc(2 * n * sizeof(double)), *rows = malloc(2 * n * sizeof(double));
    long double *ref = malloc(2 * n * sizeof(long double));
    long double *tmp = malloc(2 * (size_t)(w > h ? w : h) * sizeof(long double));
    long double big = 0.0L, err = 0.0L;
    size_t k;
    int i, j;
    if (!px || !py || !x || !y || !work || !rows || !ref || !tmp) {
        CHECK(0, "2-D %d x %d: out of memory", w, h);
        goto done;
    }
    for (k = 0; k < (size_t)nz * (size_t)w; k++) {
        x[2 * k] = signal(k, 0);
        x[2 * k + 1] = signal(k, 1);
    }
    // The reference: the rows' DFTs, then the columns' (long double throughout)
    for (j = 0; j < h; j++) {
        dft(x + 2 * (size_t)j * (size_t)w, (size_t)w, 1, 0, tmp);
        for (i = 0; i < w; i++) {
            rows[2 * ((size_t)j * (size_t)w + (size_t)i)] = (double)tmp[2 * i];
            rows[2 * ((size_t)j * (size_t)w + (size_t)i) + 1] = (double)tmp[2 * i + 1];
        }
    }
    for (i = 0; i < w; i++) {
        dft(rows + 2 * (size_t)i, (size_t)h, (size_t)w, 0, tmp);
        for (j = 0; j < h; j++) {
            ref[2 * ((size_t)j * (size_t)w + (size_t)i)] = tmp[2 * j];
            ref[2 * ((size_t)j * (size_t)w + (size_t)i) + 1] = tmp[2 * j + 1];
        }
    }
    memcpy(y, x, 2 * n * sizeof(double));
    image_fft_2d_forward(px, py, y, work, nz);
    for (k = 0; k < 2 * n; k++) {
        const long double e = fabsl((long double)y[k] - ref[k]);
        err = e > err ? e : err;
        big = fabsl(ref[k]) > big ? fabsl(ref[k]) : big;
    }
    CHECK(err <= TOL * big, "2-D %d x %d (rows >= %d zero), forward: error %Lg of %Lg", w, h, nz, err, big);
    // Back: the rows asked for are the input times w h
    image_fft_2d_inverse(px, py, y, work, r0, nr);
    err = 0.0L;
    big = 0.0L;
    for (j = r0; j < r0 + nr; j++)
        for (i = 0; i < 2 * w; i++) {
            const size_t o = 2 * (size_t)j * (size_t)w + (size_t)i;
            const long double e = fabsl((long double)y[o] / (long double)n - (long double)x[o]);
            err = e > err ? e : err;
            big = fabsl((long double)x[o]) > big ? fabsl((long double)x[o]) : big;
        }
    CHECK(err <= TOL * (big > 0 ? big : 1.0L), "2-D %d x %d, inverse of rows %d .. %d: error %Lg of %Lg", w, h, r0,
          r0 + nr - 1, err, big);
done:
    image_fft_plan_destroy(NULL, px);
    image_fft_plan_destroy(NULL, py);
    free(x);
    free(y);
    free(work);
    free(rows);
    free(ref);
    free(tmp);
}

/* The packed products: two real planes and two real kernels in two complex transforms,
 * one inverse, against each plane's own transform, product and inverse; and a plane with
 * its kernel in one transform. Cyclic convolutions on an nx x ny grid. */
static void test_packed(int nx, int ny)
{
    image_fft_plan *px = image_fft_plan_create(NULL, nx), *py = image_fft_plan_create(NULL, ny);
    const size_t n = (size_t)nx * (size_t)ny;
    double *z = malloc(2 * n * sizeof(double)), *q = malloc(2 * n * sizeof(double));
    double *s = malloc(2 * n * sizeof(double)), *sk = malloc(2 * n * sizeof(double));
    double *work = malloc(2 * n * sizeof(double)), *plane[4];
    double err = 0.0, big = 0.0;
    size_t k;
    int e;
    for (e = 0; e < 4; e++) plane[e] = malloc(n * sizeof(double));
    if (!px || !py || !z || !q || !s || !sk || !work || !plane[0] || !plane[1] || !plane[2] || !plane[3]) {
        CHECK(0, "packed %d x %d: out of memory", nx, ny);
        goto done;
    }
    for (k = 0; k < n; k++)
        for (e = 0; e < 4; e++) plane[e][k] = signal(k * 4 + (size_t)e, e % 2) + 1.5;
    for (e = 0; e < 3; e++) {
        // e 0, 1: the pair (a, b) with (ka, kb); e 2: a with ka in one transform
        for (k = 0; k < n; k++) {
            z[2 * k] = plane[0][k];
            z[2 * k + 1] = e == 2 ? plane[2][k] : plane[1][k];
            q[2 * k] = plane[2][k];
            q[2 * k + 1] = plane[3][k];
        }
        image_fft_2d_forward(px, py, z, work, ny);
        if (e == 2) {
            image_fft_packed_self_product(z, nx, ny);
        } else {
            image_fft_2d_forward(px, py, q, work, ny);
            image_fft_packed_product(z, q, nx, ny);
        }
        image_fft_2d_inverse(px, py, z, work, 0, ny);
        // The reference: plane e's and kernel e's own transforms, their product, back
        {
            const int pe = e == 1 ? 1 : 0, ke = e == 1 ? 3 : 2;
            for (k = 0; k < n; k++) {
                s[2 * k] = plane[pe][k];
                s[2 * k + 1] = 0.0;
                sk[2 * k] = plane[ke][k];
                sk[2 * k + 1] = 0.0;
            }
            image_fft_2d_forward(px, py, s, work, ny);
            image_fft_2d_forward(px, py, sk, work, ny);
            for (k = 0; k < n; k++) {
                const double re = s[2 * k] * sk[2 * k] - s[2 * k + 1] * sk[2 * k + 1];
                const double im = s[2 * k] * sk[2 * k + 1] + s[2 * k + 1] * sk[2 * k];
                s[2 * k] = re;
                s[2 * k + 1] = im;
            }
            image_fft_2d_inverse(px, py, s, work, 0, ny);
            for (k = 0; k < n; k++) {
                const double got = z[2 * k + (e == 1 ? 1 : 0)];
                err = fabs(got - s[2 * k]) > err ? fabs(got - s[2 * k]) : err;
                big = fabs(s[2 * k]) > big ? fabs(s[2 * k]) : big;
            }
        }
    }
    CHECK(err <= TOL * big, "packed products %d x %d: error %g of %g", nx, ny, err, big);
done:
    image_fft_plan_destroy(NULL, px);
    image_fft_plan_destroy(NULL, py);
    free(z);
    free(q);
    free(s);
    free(sk);
    free(work);
    for (e = 0; e < 4; e++) free(plane[e]);
}

static void test_good_sizes(void)
{
    static const int in[] = {0, 1, 2, 7, 11, 13, 17, 31, 97, 101, 1025, 1081, 1952, 2000};
    static const int want[] = {1, 1, 2, 8, 12, 15, 18, 32, 100, 108, 1080, 1125, 2000, 2000};
    size_t i;
    for (i = 0; i < sizeof in / sizeof in[0]; i++)
        CHECK(image_fft_good_size(in[i]) == want[i], "good size of %d: %d, expected %d", in[i],
              image_fft_good_size(in[i]), want[i]);
    // Every answer is 2,3,5-smooth and none smaller is
    for (i = 1; i < 3000; i++) {
        int g = image_fft_good_size((int)i), r = g, m;
        while (r % 2 == 0) r /= 2;
        while (r % 3 == 0) r /= 3;
        while (r % 5 == 0) r /= 5;
        CHECK(g >= (int)i && r == 1, "good size of %zu: %d", i, g);
        for (m = (int)i; m < g; m++) {
            int s = m;
            while (s % 2 == 0) s /= 2;
            while (s % 3 == 0) s /= 3;
            while (s % 5 == 0) s /= 5;
            if (s == 1) {
                CHECK(0, "good size of %zu: %d, but %d is smooth", i, g, m);
                break;
            }
        }
    }
}

int main(void)
{
    test_lengths();
    test_2d(8, 6, 6, 0, 6);
    test_2d(15, 12, 5, 3, 4);
    test_2d(30, 25, 25, 0, 25);
    test_2d(7, 11, 4, 10, 1);
    test_2d(64, 45, 20, 12, 20);
    test_2d(1, 9, 9, 0, 9);
    test_packed(8, 6);
    test_packed(15, 9);
    test_packed(1, 5);
    test_packed(12, 1);
    test_good_sizes();
    printf("test_fft: %d checks, %d failed\n", g_checks, g_failures);
    return g_failures == 0 ? 0 : 1;
}
