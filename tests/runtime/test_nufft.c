/* The 2-D type-1 NUFFT (runtime/src/core/nufft.c), compiled in:
 *
 *   1. against the direct sum, in long double, for odd and even mode counts (1 x 1 to
 *      64 x 64), points uniform in [-pi, pi), far outside it (|x| ~ 1e3, the reduction
 *      modulo 2 pi), clustered, and on the edges of the reduction (multiples of pi and
 *      their neighbours), tol 1e-3 to 1e-12, one vector and a batch of 5 (each checked);
 *      larger and uneven mode counts at a sample of modes, where the batch's grids pass
 *      16 MB (the points then go sorted by bin); 20 vectors (more than the 16 spread
 *      together); 140000 points (more than one block of the sort) with non-finite ones
 *      among them, and that call against the sum of two calls on parts of the points;
 *   2. one point of strength 1: f_k = exp(i k . x0);
 *   3. linearity across a batch, a call with no points (zeros, whatever the scratch held),
 *      non-finite points skipped (the same bits as without them), huge coordinates;
 *   4. the arguments refused, and sizes that never decrease with the mode counts.
 *
 * The error measure is the standard one: max over modes of |f_k - exact_k| / sum |c_j|.
 * The bound asked is 10 tol: the kernel width w = ceil(log10(1/tol)) + 1 is chosen so
 * that the kernel's own error (about 10^(1 - w)) is at most tol; the factor covers that
 * estimate being asymptotic in w and the kernel's polynomial approximation (up to 15 %
 * of it), and leaves room for rounding at tol = 1e-12 (about 1e-16 log(g) per term).
 * The errors measured stay below 1.1 tol.
 * One line is printed per check; the exit status is the number of failures (capped). */
#include "../../runtime/src/core/nufft.h"

#include <float.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define PI 3.14159265358979323846
#define NVEC 5

static int checks, failures;

/* One check: a line either way. */
static void report(int ok, const char *what, double got, double limit)
{
    checks++;
    if (!ok) failures++;
    printf("%s %s: %.3g (limit %.3g)\n", ok ? "ok  " : "FAIL", what, got, limit);
}

/* ------------------------------------------------------------------ helpers ----- */

static uint64_t rng_state = 0x9e3779b97f4a7c15ULL;

/* Uniform in [0, 1) (xorshift64*). */
static double uniform(void)
{
    rng_state ^= rng_state >> 12;
    rng_state ^= rng_state << 25;
    rng_state ^= rng_state >> 27;
    return (double)((rng_state * 0x2545f4914f6cdd1dULL) >> 11) * (1.0 / 9007199254740992.0);
}

/* A standard normal deviate (Box-Muller). */
static double normal(void)
{
    const double u = 1.0 - uniform(), v = uniform();
    return sqrt(-2.0 * log(u)) * cos(2.0 * PI * v);
}

/* A plan and its scratch for n_vec vectors, from malloc (make returns 0 on failure). */
typedef struct setup {
    lensrt_nufft p;
    void *plan_mem, *scratch;
} setup;

static int make(setup *s, int mx, int my, double tol, int n_vec)
{
    const size_t pb = lensrt_nufft_plan_bytes(mx, my, tol);
    s->plan_mem = malloc(pb);
    s->scratch = NULL;
    if (!s->plan_mem || !lensrt_nufft_init(&s->p, mx, my, tol, s->plan_mem)) return 0;
    s->scratch = malloc(lensrt_nufft_scratch_bytes(&s->p, n_vec));
    return s->scratch != NULL;
}

static void unmake(setup *s)
{
    free(s->plan_mem);
    free(s->scratch);
}

/* The direct sums of nvec vectors at the modes listed (kx[q], ky[q]), q < nk, in long
 * double (every k x_j is exact there: |k| < 2^11 times a 53-bit x), over the finite
 * points. */
static void direct(size_t n, const double *x, const double *y, int nvec, double *const *c, int nk, const int *kx,
                   const int *ky, long double *ref)
{
    size_t j;
    int q, v;
    memset(ref, 0, sizeof(long double) * 2 * (size_t)nvec * (size_t)nk);
    for (j = 0; j < n; j++) {
        if (!isfinite(x[j]) || !isfinite(y[j])) continue;
        for (q = 0; q < nk; q++) {
            const long double ph = (long double)kx[q] * x[j] + (long double)ky[q] * y[j];
            const long double er = cosl(ph), ei = sinl(ph);
            for (v = 0; v < nvec; v++) {
                const long double cr = c[v][2 * j], ci = c[v][2 * j + 1];
                ref[2 * (v * nk + q)] += cr * er - ci * ei;
                ref[2 * (v * nk + q) + 1] += cr * ei + ci * er;
            }
        }
    }
}

/* max over the listed modes of |f - ref| / sum |c| (finite points), for vector v. */
static double error(int mx, int my, const double *f, int nk, const int *kx, const int *ky,
                    const long double *ref, int v, size_t n, const double *x, const double *y, const double *c)
{
    double worst = 0.0, l1 = 0.0;
    size_t j;
    int q;
    for (j = 0; j < n; j++)
        if (isfinite(x[j]) && isfinite(y[j])) l1 += hypot(c[2 * j], c[2 * j + 1]);
    for (q = 0; q < nk; q++) {
        const size_t at = (size_t)(ky[q] + my / 2) * (size_t)mx + (size_t)(kx[q] + mx / 2);
        const double e = hypot((double)(f[2 * at] - ref[2 * (v * nk + q)]),
                               (double)(f[2 * at + 1] - ref[2 * (v * nk + q) + 1]));
        if (e > worst) worst = e;
    }
    return l1 > 0.0 ? worst / l1 : worst;
}

/* ---------------------------------------------------------- direct sums ----- */

enum { UNIFORM, FAR, CLUSTERED, EDGES, N_DIST };
static const char *dist_name[N_DIST] = {"uniform", "far", "clustered", "edges"};

/* A coordinate drawn from distribution d. */
static double coordinate(int d)
{
    switch (d) {
    case UNIFORM: return -PI + 2.0 * PI * uniform();
    case FAR: return (uniform() < 0.5 ? -1.0 : 1.0) * (900.0 + 200.0 * uniform());
    case CLUSTERED: return 0.7 + (uniform() < 0.5 ? 1e-3 : 1e-7) * normal();
    default: {
        // A multiple of pi (1 .. 1e3 turns), or its neighbour, or 0
        const double m = PI * floor(2000.0 * uniform() - 1000.0);
        const int pick = (int)(4.0 * uniform());
        return pick == 0 ? m : pick == 1 ? nextafter(m, 1e9) : pick == 2 ? nextafter(m, -1e9) : 0.0;
    }
    }
}

/* Every mode, or `sample` of them drawn at random (the first and last of each side kept). */
static int modes(int mx, int my, int sample, int *kx, int *ky)
{
    int q = 0, a, b;
    if (sample <= 0) {
        for (b = 0; b < my; b++)
            for (a = 0; a < mx; a++, q++) {
                kx[q] = a - mx / 2;
                ky[q] = b - my / 2;
            }
        return q;
    }
    kx[0] = -(mx / 2);
    ky[0] = -(my / 2);
    kx[1] = mx - 1 - mx / 2;
    ky[1] = my - 1 - my / 2;
    for (q = 2; q < sample; q++) {
        kx[q] = (int)(mx * uniform()) - mx / 2;
        ky[q] = (int)(my * uniform()) - my / 2;
    }
    return sample;
}

/* Every tol against the direct sum, one vector and NVEC, for one set of points. */
static void against_direct(int mx, int my, int d, size_t n, int sample)
{
    static const double tols[] = {1e-3, 1e-6, 1e-9, 1e-12};
    const int nk_max = sample > 0 ? sample : mx * my;
    double *x = malloc(n * sizeof *x), *y = malloc(n * sizeof *y), *cmem = malloc(NVEC * 2 * n * sizeof *cmem);
    double *fmem = malloc((size_t)NVEC * 2 * (size_t)mx * (size_t)my * sizeof *fmem);
    int *kx = malloc((size_t)nk_max * sizeof *kx), *ky = malloc((size_t)nk_max * sizeof *ky);
    long double *ref = malloc(sizeof *ref * 2 * NVEC * (size_t)nk_max);
    double *c[NVEC], *f[NVEC];
    const double *cc[NVEC];
    size_t j;
    int v, t, nk;
    if (!x || !y || !cmem || !fmem || !kx || !ky || !ref) {
        report(0, "malloc", 0, 0);
        exit(1);
    }
    for (j = 0; j < n; j++) {
        x[j] = coordinate(d);
        y[j] = coordinate(d);
    }
    for (v = 0; v < NVEC; v++) {
        cc[v] = c[v] = cmem + 2 * n * (size_t)v;
        f[v] = fmem + 2 * (size_t)mx * (size_t)my * (size_t)v;
        for (j = 0; j < 2 * n; j++) c[v][j] = 2.0 * uniform() - 1.0;
    }
    nk = modes(mx, my, sample, kx, ky);
    direct(n, x, y, NVEC, c, nk, kx, ky, ref);
    for (t = 0; t < 4; t++) {
        setup s;
        int nv;
        if (!make(&s, mx, my, tols[t], NVEC)) {
            report(0, "plan", 0, 0);
            exit(1);
        }
        for (nv = 1; nv <= NVEC; nv += NVEC - 1) {
            lensrt_nufft_type1(&s.p, n, x, y, nv, cc, f, s.scratch);
            for (v = 0; v < nv; v++) {
                char what[160];
                const double e = error(mx, my, f[v], nk, kx, ky, ref, v, n, x, y, c[v]);
                snprintf(what, sizeof what, "%dx%d %s n %zu tol %.0e w %d vector %d of %d%s", mx, my, dist_name[d], n,
                         tols[t], s.p.w, v + 1, nv, sample > 0 ? " (sampled modes)" : "");
                report(e <= 10.0 * tols[t], what, e, 10.0 * tols[t]);
            }
        }
        unmake(&s);
    }
    free(x);
    free(y);
    free(cmem);
    free(fmem);
    free(kx);
    free(ky);
    free(ref);
}

/* A batch of nvec vectors against the direct sum at `sample` modes, with every
 * `bad`-th point non-finite; and, when split > 0, the call over all points against the
 * sum of the calls over [0, split) and [split, n) (other blocks of points), to rounding. */
static void batch(int mx, int my, size_t n, int nvec, double tol, int sample, size_t bad, size_t split)
{
    double *x = malloc(n * sizeof *x), *y = malloc(n * sizeof *y);
    double *cmem = malloc((size_t)nvec * 2 * n * sizeof *cmem);
    double *fmem = malloc((size_t)nvec * 2 * (size_t)mx * (size_t)my * sizeof *fmem);
    double *gmem = malloc((size_t)nvec * 2 * (size_t)mx * (size_t)my * sizeof *gmem);
    double *hmem = malloc((size_t)nvec * 2 * (size_t)mx * (size_t)my * sizeof *hmem);
    int *kx = malloc((size_t)sample * sizeof *kx), *ky = malloc((size_t)sample * sizeof *ky);
    long double *ref = malloc(sizeof *ref * 2 * (size_t)nvec * (size_t)sample);
    double **c = calloc((size_t)nvec, sizeof *c), **f = malloc((size_t)nvec * sizeof *f);
    double **g = malloc((size_t)nvec * sizeof *g), **h = malloc((size_t)nvec * sizeof *h);
    const double **cc = malloc((size_t)nvec * sizeof *cc);
    char what[160];
    setup s;
    size_t j;
    int v, nk;
    if (!x || !y || !cmem || !fmem || !gmem || !hmem || !kx || !ky || !ref || !c || !f || !g || !h || !cc ||
        !make(&s, mx, my, tol, nvec)) {
        report(0, "malloc or plan", 0, 0);
        exit(1);
    }
    for (j = 0; j < n; j++) {
        x[j] = j % bad == 3 ? NAN : coordinate(UNIFORM);
        y[j] = j % bad == 5 ? -INFINITY : coordinate(UNIFORM);
    }
    for (v = 0; v < nvec; v++) {
        cc[v] = c[v] = cmem + 2 * n * (size_t)v;
        f[v] = fmem + 2 * (size_t)mx * (size_t)my * (size_t)v;
        g[v] = gmem + 2 * (size_t)mx * (size_t)my * (size_t)v;
        for (j = 0; j < 2 * n; j++) c[v][j] = 2.0 * uniform() - 1.0;
    }
    nk = modes(mx, my, sample, kx, ky);
    direct(n, x, y, nvec, c, nk, kx, ky, ref);
    lensrt_nufft_type1(&s.p, n, x, y, nvec, cc, f, s.scratch);
    for (v = 0; v < nvec; v++) {
        const double e = error(mx, my, f[v], nk, kx, ky, ref, v, n, x, y, c[v]);
        snprintf(what, sizeof what, "%dx%d n %zu (every %zu-th non-finite) tol %.0e vector %d of %d", mx, my, n, bad,
                 tol, v + 1, nvec);
        report(e <= 10.0 * tol, what, e, 10.0 * tol);
    }
    if (split > 0) {
        // The two parts: [0, split) into g, [split, n) into h (over the strengths' ends)
        double worst = 0.0, l1 = 0.0;
        size_t k;
        lensrt_nufft_type1(&s.p, split, x, y, nvec, cc, g, s.scratch);
        for (v = 0; v < nvec; v++) {
            cc[v] = c[v] + 2 * split;
            h[v] = hmem + 2 * (size_t)mx * (size_t)my * (size_t)v;
        }
        lensrt_nufft_type1(&s.p, n - split, x + split, y + split, nvec, cc, h, s.scratch);
        for (v = 0; v < nvec; v++) {
            for (j = 0; j < n; j++)
                if (isfinite(x[j]) && isfinite(y[j])) l1 += hypot(c[v][2 * j], c[v][2 * j + 1]);
            for (k = 0; k < 2 * (size_t)mx * (size_t)my; k++) {
                const double e = fabs(f[v][k] - (g[v][k] + h[v][k]));
                if (e > worst) worst = e;
            }
        }
        snprintf(what, sizeof what, "%dx%d n %zu x %d vectors: the sum of the calls on [0, %zu) and [%zu, n)", mx,
                 my, n, nvec, split, split);
        report(worst <= 1e-13 * l1, what, worst / l1, 1e-13);
    }
    unmake(&s);
    free(x);
    free(y);
    free(cmem);
    free(fmem);
    free(gmem);
    free(hmem);
    free(kx);
    free(ky);
    free(ref);
    free(c);
    free(f);
    free(g);
    free(h);
    free(cc);
}

/* ------------------------------------------------------------ closed forms ----- */

/* One point of strength 1 at (x0, y0): f_k = exp(i (kx x0 + ky y0)). */
static void one_point(int mx, int my, double x0, double y0, double tol)
{
    setup s;
    double *f = malloc(2 * (size_t)mx * (size_t)my * sizeof *f), worst = 0.0;
    const double one[2] = {1.0, 0.0}, *c[1];
    char what[120];
    int a, b;
    c[0] = one;
    if (!f || !make(&s, mx, my, tol, 1)) {
        report(0, "plan", 0, 0);
        exit(1);
    }
    lensrt_nufft_type1(&s.p, 1, &x0, &y0, 1, c, &f, s.scratch);
    for (b = 0; b < my; b++)
        for (a = 0; a < mx; a++) {
            const long double ph = (long double)(a - mx / 2) * x0 + (long double)(b - my / 2) * y0;
            const size_t at = (size_t)b * (size_t)mx + (size_t)a;
            const double e = hypot(f[2 * at] - (double)cosl(ph), f[2 * at + 1] - (double)sinl(ph));
            if (e > worst) worst = e;
        }
    snprintf(what, sizeof what, "one point at (%g, %g), %dx%d, tol %.0e: f = exp(i k x0)", x0, y0, mx, my, tol);
    report(worst <= 10.0 * tol, what, worst, 10.0 * tol);
    unmake(&s);
    free(f);
}

/* ------------------------------------------------------- the call's contract ----- */

/* f(a c1 + b c2) = a f(c1) + b f(c2) in one batch, to rounding. */
static void linearity(void)
{
    enum { N = 3000, MX = 40, MY = 33 };
    static double x[N], y[N], cm[3][2 * N], fm[3][2 * MX * MY];
    const double ar = 0.3, ai = -1.7, br = -2.2, bi = 0.4;
    const double *c[3] = {cm[0], cm[1], cm[2]};
    double *f[3] = {fm[0], fm[1], fm[2]}, worst = 0.0, l1 = 0.0;
    setup s;
    int j, k;
    for (j = 0; j < N; j++) {
        x[j] = 20.0 * uniform() - 10.0;
        y[j] = 20.0 * uniform() - 10.0;
        cm[0][2 * j] = uniform() - 0.5;
        cm[0][2 * j + 1] = uniform() - 0.5;
        cm[1][2 * j] = uniform() - 0.5;
        cm[1][2 * j + 1] = uniform() - 0.5;
        cm[2][2 * j] = ar * cm[0][2 * j] - ai * cm[0][2 * j + 1] + br * cm[1][2 * j] - bi * cm[1][2 * j + 1];
        cm[2][2 * j + 1] = ar * cm[0][2 * j + 1] + ai * cm[0][2 * j] + br * cm[1][2 * j + 1] + bi * cm[1][2 * j];
        l1 += hypot(cm[2][2 * j], cm[2][2 * j + 1]);
    }
    if (!make(&s, MX, MY, 1e-9, 3)) {
        report(0, "plan", 0, 0);
        exit(1);
    }
    lensrt_nufft_type1(&s.p, N, x, y, 3, c, f, s.scratch);
    for (k = 0; k < MX * MY; k++) {
        const double er = ar * fm[0][2 * k] - ai * fm[0][2 * k + 1] + br * fm[1][2 * k] - bi * fm[1][2 * k + 1];
        const double ei = ar * fm[0][2 * k + 1] + ai * fm[0][2 * k] + br * fm[1][2 * k + 1] + bi * fm[1][2 * k];
        const double e = hypot(fm[2][2 * k] - er, fm[2][2 * k + 1] - ei);
        if (e > worst) worst = e;
    }
    report(worst <= 1e-13 * l1, "linearity across a batch (error / sum |c|)", worst / l1, 1e-13);
    unmake(&s);
}

/* No points: zeros, even over a scratch and an output full of NaNs. */
static void no_points(void)
{
    enum { MX = 9, MY = 16 };
    double fm[2][2 * MX * MY], dummy = 0.0;
    const double *c[2] = {&dummy, &dummy};
    double *f[2] = {fm[0], fm[1]};
    setup s;
    int k, zero = 1;
    if (!make(&s, MX, MY, 1e-6, 2)) {
        report(0, "plan", 0, 0);
        exit(1);
    }
    memset(s.scratch, 0xff, lensrt_nufft_scratch_bytes(&s.p, 2));
    memset(fm, 0xff, sizeof fm);
    lensrt_nufft_type1(&s.p, 0, NULL, NULL, 2, c, f, s.scratch);
    for (k = 0; k < 2 * MX * MY; k++) zero &= fm[0][k] == 0.0 && fm[1][k] == 0.0;
    report(zero, "no points give zeros (1: yes)", zero, 1);
    unmake(&s);
}

/* Points with a NaN or infinite coordinate add nothing: the same bits as the call
 * without them (a small grid: the other points are spread in the same order). And huge
 * finite coordinates stay on the grid. */
static void non_finite(void)
{
    enum { N = 1000, MX = 24, MY = 17 };
    static double x[N], y[N], cv[2 * N], xs[N], ys[N], cs[2 * N], f1[2 * MX * MY], f2[2 * MX * MY];
    const double *c[1];
    double *f[1];
    setup s;
    int j, ns = 0, same = 1, finite = 1, k;
    for (j = 0; j < N; j++) {
        x[j] = 6.0 * uniform() - 3.0;
        y[j] = 6.0 * uniform() - 3.0;
        cv[2 * j] = uniform() - 0.5;
        cv[2 * j + 1] = uniform() - 0.5;
        // Every third point gets a NaN or infinite x, y or both
        if (j % 3 == 0) switch ((j / 3) % 4) {
            case 0: x[j] = NAN; break;
            case 1: y[j] = INFINITY; break;
            case 2: x[j] = -INFINITY; break;
            default: x[j] = NAN; y[j] = -INFINITY;
            }
        if (isfinite(x[j]) && isfinite(y[j])) {
            xs[ns] = x[j];
            ys[ns] = y[j];
            cs[2 * ns] = cv[2 * j];
            cs[2 * ns + 1] = cv[2 * j + 1];
            ns++;
        }
    }
    if (!make(&s, MX, MY, 1e-6, 1)) {
        report(0, "plan", 0, 0);
        exit(1);
    }
    c[0] = cv;
    f[0] = f1;
    lensrt_nufft_type1(&s.p, N, x, y, 1, c, f, s.scratch);
    c[0] = cs;
    f[0] = f2;
    lensrt_nufft_type1(&s.p, (size_t)ns, xs, ys, 1, c, f, s.scratch);
    for (k = 0; k < 2 * MX * MY; k++) {
        same &= f1[k] == f2[k];
        finite &= isfinite(f1[k]) != 0;
    }
    report(ns < N && same && finite, "non-finite points skipped: the same bits as without them (1: yes)",
           ns < N && same && finite, 1);
    // Huge finite coordinates (beyond an exact reduction): still on the grid, finite sums
    {
        const double big[6] = {1e10, -3e15, 1e300, -1e300, DBL_MAX, -DBL_MAX};
        for (j = 0; j < 6; j++) {
            x[j] = big[j];
            y[j] = big[5 - j];
        }
        c[0] = cv;
        f[0] = f1;
        lensrt_nufft_type1(&s.p, 6, x, y, 1, c, f, s.scratch);
        for (k = 0, finite = 1; k < 2 * MX * MY; k++) finite &= isfinite(f1[k]) != 0;
        report(finite, "huge coordinates (up to DBL_MAX) give finite sums (1: yes)", finite, 1);
    }
    unmake(&s);
}

/* Arguments refused, and sizes that never decrease with the mode counts. */
static void arguments(void)
{
    static double mem[4096];
    lensrt_nufft p;
    int refused = 1, grows = 1, m;
    size_t last_plan = 0, last_scratch = 0;
    refused &= lensrt_nufft_plan_bytes(0, 5, 1e-6) == 0 && lensrt_nufft_plan_bytes(5, 65537, 1e-6) == 0;
    refused &= lensrt_nufft_plan_bytes(5, 5, 1e-15) == 0 && lensrt_nufft_plan_bytes(5, 5, 0.2) == 0;
    refused &= lensrt_nufft_plan_bytes(5, 5, NAN) == 0;
    refused &= !lensrt_nufft_init(&p, 0, 5, 1e-6, mem) && !lensrt_nufft_init(&p, 5, -1, 1e-6, mem);
    refused &= !lensrt_nufft_init(&p, 65537, 5, 1e-6, mem) && !lensrt_nufft_init(&p, 5, 5, 1e-15, mem);
    refused &= !lensrt_nufft_init(&p, 5, 5, NAN, mem) && !lensrt_nufft_init(&p, 5, 5, 0.5, mem);
    refused &= !lensrt_nufft_init(&p, 5, 5, 1e-6, NULL) && !lensrt_nufft_init(NULL, 5, 5, 1e-6, mem);
    refused &= !lensrt_nufft_init(&p, 5, 5, 1e-6, (char *)mem + 4);
    refused &= lensrt_nufft_plan_bytes(5, 5, 1e-6) <= sizeof mem && lensrt_nufft_init(&p, 5, 5, 1e-6, mem);
    refused &= lensrt_nufft_scratch_bytes(&p, 0) == 0 && lensrt_nufft_scratch_bytes(&p, 1) > 0;
    refused &= lensrt_nufft_plan_bytes(65536, 65536, 1e-14) > 0;
    report(refused, "bad arguments refused, good ones taken (1: yes)", refused, 1);
    for (m = 1; m <= 300; m++) {
        const size_t pb = lensrt_nufft_plan_bytes(m, m / 2 + 1, 1e-9);
        size_t sb;
        static double big[1 << 14];
        if (pb > sizeof big || !lensrt_nufft_init(&p, m, m / 2 + 1, 1e-9, big)) {
            grows = 0;
            break;
        }
        sb = lensrt_nufft_scratch_bytes(&p, 7);
        grows &= pb >= last_plan && sb >= last_scratch;
        last_plan = pb;
        last_scratch = sb;
    }
    report(grows, "plan and scratch bytes never decrease with the modes (1: yes)", grows, 1);
}

int main(void)
{
    static const int sizes[][2] = {{1, 1}, {1, 7}, {7, 1}, {8, 8}, {17, 12}, {32, 24}};
    size_t i;
    int d;
    for (i = 0; i < sizeof sizes / sizeof sizes[0]; i++)
        for (d = 0; d < N_DIST; d++) against_direct(sizes[i][0], sizes[i][1], d, 700, 0);
    // Larger and uneven grids, at 300 sampled modes (the first two's 5 grids pass 16 MB)
    against_direct(256, 256, UNIFORM, 3000, 300);
    against_direct(100, 257, FAR, 3000, 300);
    against_direct(3, 520, CLUSTERED, 3000, 300);
    // More vectors than are spread together (16); more points than are sorted at once
    // (65536), into grids beyond 16 MB (so sorted), with non-finite points among them
    batch(12, 9, 500, 20, 1e-9, 108, 7, 0);
    batch(256, 200, 140000, 6, 1e-6, 12, 997, 70001);
    one_point(33, 20, 1.234, -2.5, 1e-6);
    one_point(33, 20, -1e3 + 0.1, 3e3 / 7.0, 1e-12);
    one_point(1, 1, 0.5, 0.5, 1e-3);
    linearity();
    no_points();
    non_finite();
    arguments();
    printf("%d checks, %d failed\n", checks, failures);
    return failures > 100 ? 100 : failures;
}
