/* The complex FFT (fft.h): Stockham autosort passes, mixed radix.
 *
 * One pass of radix r over a sequence of length n seen as s interleaved subsequences of
 * length L = n / s (s = the product of the radices already done), m = L / r:
 *
 *   for p < m, q < s:  a_j = x[q + s (p + j m)],  j < r
 *                      y[q + s (r p + k)] = (sum_j a_j W_r^{j k}) W_L^{p k},  k < r
 *
 * (decimation in frequency; W_L = exp(-2 pi i / L), and W_L^{p k} = W_n^{p k s}, read from
 * the plan's table at index p k s < n). After the last pass the output is in natural
 * order: no bit reversal. `howmany` sequences interleaved element by element are done at
 * once by running q over s howmany (the twiddles depend on p only). Each pass reads one
 * buffer and writes the other; the result is copied back when it ends in the work one. */
#include "fft.h"

#include "../internal.h"

#include <math.h>
#include <string.h>

#define FFT_PI 3.14159265358979323846

int image_fft_good_size(int n)
{
    long best = 0, p2, p3, p5;
    if (n <= 1) return 1;
    if (n > (1 << 30)) return 0;
    // Every 2^a 3^b 5^c up to 2^30: keep the smallest >= n
    for (p5 = 1; p5 <= (1L << 30); p5 *= 5)
        for (p3 = p5; p3 <= (1L << 30); p3 *= 3) {
            for (p2 = p3; p2 < n; p2 *= 2) continue;
            if (p2 <= (1L << 30) && (best == 0 || p2 < best)) best = p2;
        }
    return (int)best;
}

image_fft_plan *image_fft_plan_create(lensrt_context ctx, int n)
{
    image_fft_plan *plan;
    int rest = n, f, t;
    if (n < 1) return NULL;
    plan = lensrt_calloc(ctx, 1, sizeof *plan);
    if (!plan) return NULL;
    plan->n = n;
    plan->twiddle = lensrt_alloc(ctx, 2 * (size_t)n * sizeof(double));
    if (!plan->twiddle) {
        lensrt_free(ctx, plan);
        return NULL;
    }
    // The twiddles, each from its own angle (no recurrence: every one to within an ulp or two)
    for (t = 0; t < n; t++) {
        const double a = -2.0 * FFT_PI * (double)t / (double)n;
        plan->twiddle[2 * t] = cos(a);
        plan->twiddle[2 * t + 1] = sin(a);
    }
    // The radices: 4s first (the cheapest pass per element), then 2, 3, 5, then any other
    // prime factor (a plain butterfly); at most log2(n) < 64 of them
    while (rest % 4 == 0) {
        plan->factors[plan->n_factors++] = 4;
        rest /= 4;
    }
    for (f = 2; rest > 1; f++)
        while (rest % f == 0) {
            plan->factors[plan->n_factors++] = f;
            rest /= f;
        }
    return plan;
}

void image_fft_plan_destroy(lensrt_context ctx, image_fft_plan *plan)
{
    if (!plan) return;
    lensrt_free(ctx, plan->twiddle);
    lensrt_free(ctx, plan);
}

/* (a + ib)(c + id) into (re, im) */
#define CMUL_RE(a, b, c, d) ((a) * (c) - (b) * (d))
#define CMUL_IM(a, b, c, d) ((a) * (d) + (b) * (c))

/* Multiply y's complex value at index o by the twiddle (wr, wi) */
static void twiddle_mul(double *y, size_t o, double wr, double wi)
{
    const double re = y[2 * o], im = y[2 * o + 1];
    y[2 * o] = CMUL_RE(re, im, wr, wi);
    y[2 * o + 1] = CMUL_IM(re, im, wr, wi);
}

/* One pass of radix r (see the top of the file); sg = -1 forward, +1 inverse (the sign
 * of the exponent). */
static void fft_pass(const image_fft_plan *plan, int r, size_t s, size_t howmany, const double *x, double *y,
                     double sg)
{
    const size_t n = (size_t)plan->n, len = n / s, m = len / (size_t)r, S = s * howmany;
    const double *tw = plan->twiddle;
    size_t p, q;
    for (p = 0; p < m; p++) {
        // This p's twiddles W_L^{p k} (conjugated for the inverse)
        double wr[8], wi[8];
        int k;
        for (k = 1; k < r && k < 8; k++) {
            const size_t t = p * (size_t)k * s;
            wr[k] = tw[2 * t];
            wi[k] = sg < 0 ? tw[2 * t + 1] : -tw[2 * t + 1];
        }
        if (r == 2) {
            for (q = 0; q < S; q++) {
                const size_t i0 = q + S * p, i1 = i0 + S * m, o0 = q + S * 2 * p, o1 = o0 + S;
                const double ar = x[2 * i0], ai = x[2 * i0 + 1], br = x[2 * i1], bi = x[2 * i1 + 1];
                y[2 * o0] = ar + br;
                y[2 * o0 + 1] = ai + bi;
                y[2 * o1] = CMUL_RE(ar - br, ai - bi, wr[1], wi[1]);
                y[2 * o1 + 1] = CMUL_IM(ar - br, ai - bi, wr[1], wi[1]);
            }
        } else if (r == 4) {
            for (q = 0; q < S; q++) {
                const size_t i0 = q + S * p, o0 = q + S * 4 * p;
                const double a0r = x[2 * i0], a0i = x[2 * i0 + 1];
                const double a1r = x[2 * (i0 + S * m)], a1i = x[2 * (i0 + S * m) + 1];
                const double a2r = x[2 * (i0 + 2 * S * m)], a2i = x[2 * (i0 + 2 * S * m) + 1];
                const double a3r = x[2 * (i0 + 3 * S * m)], a3i = x[2 * (i0 + 3 * S * m) + 1];
                // (a1 - a3) times sg i: the odd outputs' imaginary part
                const double t0r = a0r + a2r, t0i = a0i + a2i, t1r = a0r - a2r, t1i = a0i - a2i;
                const double t2r = a1r + a3r, t2i = a1i + a3i, t3r = -sg * (a1i - a3i), t3i = sg * (a1r - a3r);
                double b1r = t1r + t3r, b1i = t1i + t3i, b2r = t0r - t2r, b2i = t0i - t2i;
                double b3r = t1r - t3r, b3i = t1i - t3i;
                y[2 * o0] = t0r + t2r;
                y[2 * o0 + 1] = t0i + t2i;
                y[2 * (o0 + S)] = CMUL_RE(b1r, b1i, wr[1], wi[1]);
                y[2 * (o0 + S) + 1] = CMUL_IM(b1r, b1i, wr[1], wi[1]);
                y[2 * (o0 + 2 * S)] = CMUL_RE(b2r, b2i, wr[2], wi[2]);
                y[2 * (o0 + 2 * S) + 1] = CMUL_IM(b2r, b2i, wr[2], wi[2]);
                y[2 * (o0 + 3 * S)] = CMUL_RE(b3r, b3i, wr[3], wi[3]);
                y[2 * (o0 + 3 * S) + 1] = CMUL_IM(b3r, b3i, wr[3], wi[3]);
            }
        } else if (r == 3) {
            // W_3 = -1/2 + sg i sqrt(3)/2
            const double c = -0.5, sn = sg * 0.86602540378443864676;
            for (q = 0; q < S; q++) {
                const size_t i0 = q + S * p, o0 = q + S * 3 * p;
                const double a0r = x[2 * i0], a0i = x[2 * i0 + 1];
                const double a1r = x[2 * (i0 + S * m)], a1i = x[2 * (i0 + S * m) + 1];
                const double a2r = x[2 * (i0 + 2 * S * m)], a2i = x[2 * (i0 + 2 * S * m) + 1];
                const double tr = a1r + a2r, ti = a1i + a2i, mr = a0r + c * tr, mi = a0i + c * ti;
                // sn i (a1 - a2)
                const double dr = -sn * (a1i - a2i), di = sn * (a1r - a2r);
                y[2 * o0] = a0r + tr;
                y[2 * o0 + 1] = a0i + ti;
                y[2 * (o0 + S)] = CMUL_RE(mr + dr, mi + di, wr[1], wi[1]);
                y[2 * (o0 + S) + 1] = CMUL_IM(mr + dr, mi + di, wr[1], wi[1]);
                y[2 * (o0 + 2 * S)] = CMUL_RE(mr - dr, mi - di, wr[2], wi[2]);
                y[2 * (o0 + 2 * S) + 1] = CMUL_IM(mr - dr, mi - di, wr[2], wi[2]);
            }
        } else if (r == 5) {
            // W_5^k = cos(2 pi k / 5) + sg i sin(2 pi k / 5)
            const double c1 = 0.30901699437494742410, c2 = -0.80901699437494742410;
            const double s1 = sg * 0.95105651629515357212, s2 = sg * 0.58778525229247312917;
            for (q = 0; q < S; q++) {
                const size_t i0 = q + S * p, o0 = q + S * 5 * p;
                double a[5][2], b[5][2];
                int j;
                for (j = 0; j < 5; j++) {
                    a[j][0] = x[2 * (i0 + (size_t)j * S * m)];
                    a[j][1] = x[2 * (i0 + (size_t)j * S * m) + 1];
                }
                {
                    const double t1r = a[1][0] + a[4][0], t1i = a[1][1] + a[4][1];
                    const double t2r = a[2][0] + a[3][0], t2i = a[2][1] + a[3][1];
                    const double d1r = a[1][0] - a[4][0], d1i = a[1][1] - a[4][1];
                    const double d2r = a[2][0] - a[3][0], d2i = a[2][1] - a[3][1];
                    const double m1r = a[0][0] + c1 * t1r + c2 * t2r, m1i = a[0][1] + c1 * t1i + c2 * t2i;
                    const double m2r = a[0][0] + c2 * t1r + c1 * t2r, m2i = a[0][1] + c2 * t1i + c1 * t2i;
                    // i (s1 d1 + s2 d2) and i (s2 d1 - s1 d2)
                    const double e1r = -(s1 * d1i + s2 * d2i), e1i = s1 * d1r + s2 * d2r;
                    const double e2r = -(s2 * d1i - s1 * d2i), e2i = s2 * d1r - s1 * d2r;
                    b[0][0] = a[0][0] + t1r + t2r;
                    b[0][1] = a[0][1] + t1i + t2i;
                    b[1][0] = m1r + e1r;
                    b[1][1] = m1i + e1i;
                    b[4][0] = m1r - e1r;
                    b[4][1] = m1i - e1i;
                    b[2][0] = m2r + e2r;
                    b[2][1] = m2i + e2i;
                    b[3][0] = m2r - e2r;
                    b[3][1] = m2i - e2i;
                }
                y[2 * o0] = b[0][0];
                y[2 * o0 + 1] = b[0][1];
                for (j = 1; j < 5; j++) {
                    y[2 * (o0 + (size_t)j * S)] = CMUL_RE(b[j][0], b[j][1], wr[j], wi[j]);
                    y[2 * (o0 + (size_t)j * S) + 1] = CMUL_IM(b[j][0], b[j][1], wr[j], wi[j]);
                }
            }
        } else {
            // Any other prime: the butterfly's plain sums, W_r^t = W_n^{(t mod r) n / r}
            const size_t step = n / (size_t)r;
            for (q = 0; q < S; q++) {
                const size_t i0 = q + S * p, o0 = q + S * (size_t)r * p;
                for (k = 0; k < r; k++) {
                    double sr = 0.0, si = 0.0;
                    int j;
                    for (j = 0; j < r; j++) {
                        const size_t t = ((size_t)j * (size_t)k) % (size_t)r * step;
                        const double er = tw[2 * t], ei = sg < 0 ? tw[2 * t + 1] : -tw[2 * t + 1];
                        const double ar = x[2 * (i0 + (size_t)j * S * m)], ai = x[2 * (i0 + (size_t)j * S * m) + 1];
                        sr += CMUL_RE(ar, ai, er, ei);
                        si += CMUL_IM(ar, ai, er, ei);
                    }
                    y[2 * (o0 + (size_t)k * S)] = sr;
                    y[2 * (o0 + (size_t)k * S) + 1] = si;
                    if (k > 0) {
                        const size_t t = p * (size_t)k * s;
                        twiddle_mul(y, o0 + (size_t)k * S, tw[2 * t], sg < 0 ? tw[2 * t + 1] : -tw[2 * t + 1]);
                    }
                }
            }
        }
    }
}

void image_fft_many(const image_fft_plan *plan, double *data, double *work, size_t howmany, int inverse)
{
    const double sg = inverse ? 1.0 : -1.0;
    double *x = data, *y = work, *t;
    size_t s = 1;
    int f;
    // Each pass from one buffer into the other, s growing by its radix
    for (f = 0; f < plan->n_factors; f++) {
        fft_pass(plan, plan->factors[f], s, howmany, x, y, sg);
        s *= (size_t)plan->factors[f];
        t = x;
        x = y;
        y = t;
    }
    // The result is in x: bring it home when that is the work buffer
    if (x != data) memcpy(data, x, 2 * (size_t)plan->n * howmany * sizeof(double));
}

void image_fft_2d_forward(const image_fft_plan *rows, const image_fft_plan *cols, double *data, double *work,
                          int n_rows)
{
    const size_t w = (size_t)rows->n;
    int j;
    // The rows that hold anything, one by one (contiguous); then all the columns in one
    // batched pass
    for (j = 0; j < n_rows && j < cols->n; j++) image_fft_many(rows, data + 2 * (size_t)j * w, work, 1, 0);
    image_fft_many(cols, data, work, w, 0);
}

void image_fft_2d_inverse(const image_fft_plan *rows, const image_fft_plan *cols, double *data, double *work,
                          int first_row, int n_rows)
{
    const size_t w = (size_t)rows->n;
    int j;
    // Every column, then the rows asked for
    image_fft_many(cols, data, work, w, 1);
    for (j = first_row < 0 ? 0 : first_row; j < first_row + n_rows && j < cols->n; j++)
        image_fft_many(rows, data + 2 * (size_t)j * w, work, 1, 1);
}

void image_fft_packed_product(double *z, const double *q, int nx, int ny)
{
    int u, v;
    for (v = 0; v < ny; v++) {
        const int vm = v == 0 ? 0 : ny - v;
        for (u = 0; u < nx; u++) {
            const int um = u == 0 ? 0 : nx - u;
            const size_t a = (size_t)v * (size_t)nx + (size_t)u, b = (size_t)vm * (size_t)nx + (size_t)um;
            double ar, ai, br, bi, kar, kai, kbr, kbi, p1r, p1i, p2r, p2i;
            if (b < a) continue;
            ar = 0.5 * (z[2 * a] + z[2 * b]);
            ai = 0.5 * (z[2 * a + 1] - z[2 * b + 1]);
            br = 0.5 * (z[2 * a + 1] + z[2 * b + 1]);
            bi = -0.5 * (z[2 * a] - z[2 * b]);
            kar = 0.5 * (q[2 * a] + q[2 * b]);
            kai = 0.5 * (q[2 * a + 1] - q[2 * b + 1]);
            kbr = 0.5 * (q[2 * a + 1] + q[2 * b + 1]);
            kbi = -0.5 * (q[2 * a] - q[2 * b]);
            p1r = ar * kar - ai * kai;
            p1i = ar * kai + ai * kar;
            p2r = br * kbr - bi * kbi;
            p2i = br * kbi + bi * kbr;
            // Y(f) = P1 + i P2; Y(-f) = conj P1 + i conj P2
            z[2 * a] = p1r - p2i;
            z[2 * a + 1] = p1i + p2r;
            z[2 * b] = p1r + p2i;
            z[2 * b + 1] = p2r - p1i;
        }
    }
}

void image_fft_packed_self_product(double *z, int nx, int ny)
{
    int u, v;
    for (v = 0; v < ny; v++) {
        const int vm = v == 0 ? 0 : ny - v;
        for (u = 0; u < nx; u++) {
            const int um = u == 0 ? 0 : nx - u;
            const size_t a = (size_t)v * (size_t)nx + (size_t)u, b = (size_t)vm * (size_t)nx + (size_t)um;
            double ar, ai, br, bi, pr, pi;
            if (b < a) continue;
            ar = 0.5 * (z[2 * a] + z[2 * b]);
            ai = 0.5 * (z[2 * a + 1] - z[2 * b + 1]);
            br = 0.5 * (z[2 * a + 1] + z[2 * b + 1]);
            bi = -0.5 * (z[2 * a] - z[2 * b]);
            pr = ar * br - ai * bi;
            pi = ar * bi + ai * br;
            // Y(f) = A B, Y(-f) = conj(A B): a real plane's spectrum
            z[2 * a] = pr;
            z[2 * a + 1] = pi;
            z[2 * b] = pr;
            z[2 * b + 1] = -pi;
        }
    }
}
