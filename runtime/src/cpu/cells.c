/* The CPU device's cells integrator (core/cells.h): per wavelength, the mesh vertices'
 * rows, phases, amplitudes and clip levels before the stop (in parallel over vertices),
 * then per pixel (in parallel over pixels) the transport after the stop at every vertex
 * and the closed-form integral over every triangle, cut where a clip crosses it.
 *
 * Everything is in double. The pixel's terms are the Monte Carlo kernel's own
 * (lensrt_cpu_setup_pixel: pruned to the render's phase tolerance, in the window's
 * basis), so both integrators integrate the same function. */
#include "pass.h"

#include "../core/cells.h"
#include "../lens/lens.h"

#include <math.h>
#include <string.h>
#ifdef LENSRT_OPENMP
#include <omp.h>
#endif

#define TWO_PI 6.283185307179586477
/* Log amplitudes below this (amplitude 0: intensity 0 or no transmittance) are held
 * there: e^-80 is 2e-35 of a unit amplitude, nothing in a float image. */
#define LOG_AMP_FLOOR (-80.0)

/* One wavelength's vertex data: rows [v][n_rows]; per light l the phase in waves
 * relative to vertex 0 (sph), the log amplitude (lna) and the levels before the stop
 * (lev_o [l][v][n_lev_o]). */
typedef struct cells_vertices {
    int n, n_rows, n_lev_o;
    double *rows, *sph, *lna, *lev_o;
    float *rows_f;
} cells_vertices;

static void free_vertices(lensrt_context ctx, cells_vertices *cv)
{
    lensrt_free(ctx, cv->rows);
    lensrt_free(ctx, cv->rows_f);
    lensrt_free(ctx, cv->sph);
    lensrt_free(ctx, cv->lna);
    lensrt_free(ctx, cv->lev_o);
    memset(cv, 0, sizeof *cv);
}

static int alloc_vertices(lensrt_render r, const lensrt_mesh *m, cells_vertices *cv)
{
    const size_t nv = (size_t)m->n_vertices, nl = (size_t)r->n_lights;
    memset(cv, 0, sizeof *cv);
    cv->n = m->n_vertices;
    cv->n_rows = r->n_rows;
    cv->rows = lensrt_calloc(r->ctx, nv * (size_t)r->n_rows, sizeof(double));
    cv->rows_f = lensrt_calloc(r->ctx, (size_t)r->n_rows, sizeof(float) * 64); /* per thread: [64][n_rows] */
    cv->sph = lensrt_calloc(r->ctx, nv * nl, sizeof(double));
    cv->lna = lensrt_calloc(r->ctx, nv * nl, sizeof(double));
    cv->lev_o = lensrt_calloc(r->ctx, nv * nl * (1 + LENSRT_MAX_CLIP_PAIRS), sizeof(double));
    if (!cv->rows || !cv->rows_f || !cv->sph || !cv->lna || !cv->lev_o) {
        free_vertices(r->ctx, cv);
        return 0;
    }
    return 1;
}

/* Vertex v: the lens kind's rows (in double), and per light the wave at the stop. The
 * phase is kept unreduced (the triangles need its differences), relative to vertex 0's
 * so that it stays a few thousand waves at most. */
static void prepare_vertex(const lensrt_render r, int w, const lensrt_mesh *m, cells_vertices *cv, long v, float *rf)
{
    const lensrt_lens_ops *ops = r->lens_ops;
    const double lambda_mm = r->wavelengths[w] / LENSRT_NM_PER_MM;
    const double x = m->xy[2 * v], y = m->xy[2 * v + 1];
    const int nr = r->n_rows;
    double mono[136], *row = cv->rows + (size_t)v * (size_t)nr;
    lensrt_rows rows;
    int l, k;
    rows.stride = 1;
    rows.d = row;
    rows.f = rf;
    ops->sample_rows(r, w, x, y, mono, &rows);
    if (!r->double_rows)
        for (k = 0; k < nr; k++) row[k] = (double)rf[k];
    for (l = 0; l < r->n_lights; l++) {
        const size_t at = (size_t)l * (size_t)cv->n + (size_t)v;
        double amp = sqrt(r->lights[l].intensity), opl = 0.0;
        int n_lev = 0;
        if (ops->sample_levels) n_lev = ops->sample_levels(r, w, l, mono, &amp, &opl, cv->lev_o + at * (1 + LENSRT_MAX_CLIP_PAIRS));
        else ops->sample_wave(r, w, l, x, y, mono, &amp, &opl);
        cv->n_lev_o = n_lev;
        cv->sph[at] = opl / lambda_mm;
        cv->lna[at] = amp > 0.0 ? fmax(log(amp), LOG_AMP_FLOOR) : LOG_AMP_FLOOR;
    }
}

/* Per-thread scratch for one pixel: per vertex the pixel's phase (waves), log amplitude
 * and levels after the stop, then per light z = (2 pi phase, -log amp) and exp(i z). */
typedef struct cells_scratch {
    double *ph, *lnt, *lev_p, *z, *E, *lev;
    unsigned char *in; /* every level >= 0 at the vertex */
} cells_scratch;

#define MAX_LEV_P (1 + LENSRT_MAX_CLIP_PAIRS)

/* A level of x^2 + y^2 <= r2: (r2 - x^2 - y^2) / (2 sqrt(r2)), mm-like near its zero. */
static double disc_level(double r2, double x, double y)
{
    return (r2 - (x * x + y * y)) / (2.0 * (r2 > 0.0 ? sqrt(r2) : 1.0));
}

static double dot_terms(const lensrt_terms_d *t, const double *row)
{
    double s = 0.0;
    int k;
    for (k = 0; k < t->n; k++) s += t->coef[k] * row[t->slot[k]];
    return s;
}

/* The pixel's part at every vertex: phase in waves, log transmittance (and the free-space
 * kernel's log amplitude), the levels after the stop. Returns their count, or -1 when
 * every path through the pixel is clipped. *amp: the pixel's constant amplitude. */
static int pixel_vertices(lensrt_render r, int w, long p, const cells_vertices *cv, cells_scratch *s, double *amp)
{
    const double x = r->xs[p % r->width], y = r->ys[p / r->width];
    const int nv = cv->n, nr = cv->n_rows;
    int v, n_lev = 0;
    if (r->lens_ops->transport == LENSRT_TRANSPORT_FREE_SPACE) {
        // Rayleigh-Sommerfeld: the distance in waves and cos(theta) / (lambda r)
        const lensrt_analytic_lens *mdl = &r->lens->model;
        const double z = mdl->sensor_distance_mm + r->desc.sensor.focus_offset_mm;
        const double lambda_mm = r->wavelengths[w] / LENSRT_NM_PER_MM;
        for (v = 0; v < nv; v++) {
            const double dx = x - cv->rows[(size_t)v * nr], dy = y - cv->rows[(size_t)v * nr + 1];
            const double r2 = dx * dx + dy * dy + z * z;
            s->ph[v] = sqrt(r2) / lambda_mm;
            s->lnt[v] = log(z / (lambda_mm * r2));
        }
        *amp = 1.0;
        return 0;
    }
    {
        lensrt_cpu_pixel px;
        lensrt_cpu_clip clip;
        const lensrt_pixel_d *d = &px.d;
        int q;
        if (!lensrt_cpu_setup_pixel(r, w, x, y, &px, r->clip_s ? &clip : NULL)) return -1;
        *amp = px.amp;
        n_lev = (d->clip ? 1 : 0) + d->n_clip;
        for (v = 0; v < nv; v++) {
            const double *row = cv->rows + (size_t)v * nr;
            double *lv = s->lev_p + (size_t)v * MAX_LEV_P;
            int j = 0;
            s->ph[v] = dot_terms(&d->phase, row);
            if (d->tau.n > 0) {
                const double t = dot_terms(&d->tau, row);
                s->lnt[v] = t > 0.0 ? fmax(0.5 * log(t), LOG_AMP_FLOOR) : LOG_AMP_FLOOR;
            } else {
                s->lnt[v] = 0.0;
            }
            if (d->clip) lv[j++] = disc_level(d->housing2, dot_terms(&d->xi, row), dot_terms(&d->yi, row));
            for (q = 0; q < d->n_clip; q++) {
                const double hx = dot_terms(&d->clip_x[q], row), hy = dot_terms(&d->clip_y[q], row);
                double e = disc_level(d->clip_r2[q], hx, hy);
                if (d->clip_shaped[q]) {
                    const double f = lensrt_stop_shape_level(d->stop, hx, hy);
                    if (f < e) e = f;
                }
                lv[j++] = e;
            }
        }
    }
    return n_lev;
}

/* One pixel's fields for every light: U[l] (re, im). */
static void integrate_pixel(lensrt_render r, int w, long p, const lensrt_mesh *m, const cells_vertices *cv,
                            cells_scratch *s, double *U)
{
    const int nv = cv->n, nt = m->n_triangles, n_lev_o = cv->n_lev_o;
    double amp = 1.0;
    int l, v, t, n_lev_p = pixel_vertices(r, w, p, cv, s, &amp), n_lev;
    for (l = 0; l < r->n_lights; l++) U[2 * l] = U[2 * l + 1] = 0.0;
    if (n_lev_p < 0) return; /* dark */
    n_lev = n_lev_o + n_lev_p;
    for (l = 0; l < r->n_lights; l++) {
        const double *sph = cv->sph + (size_t)l * nv, *lna = cv->lna + (size_t)l * nv;
        const double *lev_o = cv->lev_o + (size_t)l * nv * (1 + LENSRT_MAX_CLIP_PAIRS);
        const double ref = s->ph[0] + sph[0];
        double acc[2] = {0.0, 0.0};
        if (r->lights[l].intensity <= 0.0) continue;
        // z and exp(i z) per vertex: the phase relative to vertex 0 in radians, minus i
        // the log amplitude (so that log A is interpolated with the phase)
        for (v = 0; v < nv; v++) {
            const double ph = TWO_PI * ((s->ph[v] + sph[v]) - ref), la = lna[v] + s->lnt[v], a = exp(la);
            s->z[2 * v] = ph;
            s->z[2 * v + 1] = -la;
            s->E[2 * v] = a * cos(ph);
            s->E[2 * v + 1] = a * sin(ph);
        }
        if (n_lev == 0) {
            for (t = 0; t < nt; t++) {
                const int *tv = m->tri + 3 * t;
                double z[6], E[6], o[2];
                int k;
                for (k = 0; k < 3; k++) {
                    z[2 * k] = s->z[2 * tv[k]];
                    z[2 * k + 1] = s->z[2 * tv[k] + 1];
                    E[2 * k] = s->E[2 * tv[k]];
                    E[2 * k + 1] = s->E[2 * tv[k] + 1];
                }
                lensrt_tri_integral(m->area[t], z, E, o);
                acc[0] += o[0];
                acc[1] += o[1];
            }
        } else {
            // The levels before the stop (this light's) and after it (this pixel's)
            for (v = 0; v < nv; v++) {
                double *lv = s->lev + (size_t)v * n_lev;
                int j, in = 1;
                for (j = 0; j < n_lev_o; j++) lv[j] = lev_o[(size_t)v * (1 + LENSRT_MAX_CLIP_PAIRS) + j];
                for (j = 0; j < n_lev_p; j++) lv[n_lev_o + j] = s->lev_p[(size_t)v * MAX_LEV_P + j];
                for (j = 0; j < n_lev; j++) in &= lv[j] >= 0.0;
                s->in[v] = (unsigned char)in;
            }
            for (t = 0; t < nt; t++) {
                const int *tv = m->tri + 3 * t;
                double z[6], E[6], lev[3 * LENSRT_CELLS_MAX_LEVELS], o[2];
                int k, j;
                for (k = 0; k < 3; k++) {
                    z[2 * k] = s->z[2 * tv[k]];
                    z[2 * k + 1] = s->z[2 * tv[k] + 1];
                    E[2 * k] = s->E[2 * tv[k]];
                    E[2 * k + 1] = s->E[2 * tv[k] + 1];
                }
                // Wholly inside every clip (most triangles): no cutting
                if (s->in[tv[0]] && s->in[tv[1]] && s->in[tv[2]]) {
                    lensrt_tri_integral(m->area[t], z, E, o);
                    acc[0] += o[0];
                    acc[1] += o[1];
                    continue;
                }
                for (k = 0; k < 3; k++)
                    for (j = 0; j < n_lev; j++) lev[k * n_lev + j] = s->lev[(size_t)tv[k] * n_lev + j];
                lensrt_tri_integral_clipped(m->area[t], z, E, lev, n_lev, acc);
            }
        }
        U[2 * l] = amp * acc[0];
        U[2 * l + 1] = amp * acc[1];
    }
}

lensrt_result lensrt_cpu_cells(lensrt_render r, const lensrt_mesh *m, double *U, lensrt_progress_fn progress,
                               void *user_data, double frac0, double frac1)
{
    const long npix = (long)r->width * r->height;
    const int nthreads =
#ifdef LENSRT_OPENMP
        r->ctx->threads > 0 ? r->ctx->threads : omp_get_max_threads();
#else
        1;
#endif
    const size_t nv = (size_t)m->n_vertices;
    cells_vertices cv;
    double *scratch;
    const size_t per_thread = nv * (3 + MAX_LEV_P + 4 + LENSRT_CELLS_MAX_LEVELS);
    /* ph, lnt (nv each), lev_p (MAX_LEV_P nv), z, E (2 nv each), lev (MAX_LEVELS nv),
     * in (nv bytes in the last nv doubles) */
    double t0 = lensrt_seconds();
    int w, failed = 0;
    if (!alloc_vertices(r, m, &cv)) return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "cells: out of memory");
    lensrt_free(r->ctx, cv.rows_f);
    cv.rows_f = lensrt_calloc(r->ctx, (size_t)nthreads * (size_t)(r->n_rows > 0 ? r->n_rows : 1), sizeof(float));
    scratch = lensrt_calloc(r->ctx, per_thread * (size_t)nthreads, sizeof(double));
    if (!scratch || !cv.rows_f) {
        lensrt_free(r->ctx, scratch);
        free_vertices(r->ctx, &cv);
        return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "cells: out of memory for %d threads' scratch", nthreads);
    }
    for (w = 0; w < r->n_wl && !failed; w++) {
        long v, p;
        // The vertices' side before the stop, in parallel over vertices
#ifdef LENSRT_OPENMP
#pragma omp parallel for schedule(static) num_threads(nthreads)
#endif
        for (v = 0; v < (long)nv; v++) {
            int th =
#ifdef LENSRT_OPENMP
                omp_get_thread_num();
#else
                0;
#endif
            prepare_vertex(r, w, m, &cv, v, cv.rows_f + (size_t)th * (size_t)r->n_rows);
        }
        // Every pixel, in parallel over pixels (each writes only its own fields)
#ifdef LENSRT_OPENMP
#pragma omp parallel for schedule(dynamic, 4) num_threads(nthreads)
#endif
        for (p = 0; p < npix; p++) {
            int th =
#ifdef LENSRT_OPENMP
                omp_get_thread_num();
#else
                0;
#endif
            double *base = scratch + per_thread * (size_t)th, f[2 * LENSRT_MAX_LIGHTS];
            cells_scratch s;
            int l;
            s.ph = base;
            s.lnt = base + nv;
            s.lev_p = base + 2 * nv;
            s.z = base + (2 + MAX_LEV_P) * nv;
            s.E = base + (4 + MAX_LEV_P) * nv;
            s.lev = base + (6 + MAX_LEV_P) * nv;
            s.in = (unsigned char *)(base + (6 + MAX_LEV_P + LENSRT_CELLS_MAX_LEVELS) * nv);
            integrate_pixel(r, w, p, m, &cv, &s, f);
            for (l = 0; l < r->n_lights; l++) {
                const size_t at = ((size_t)l * (size_t)r->n_wl + (size_t)w) * (size_t)npix + (size_t)p;
                U[2 * at] = f[2 * l];
                U[2 * at + 1] = f[2 * l + 1];
            }
        }
        if (progress) {
            const double frac = frac0 + (frac1 - frac0) * (w + 1) / r->n_wl, el = lensrt_seconds() - t0;
            if (progress(frac, el * (frac1 - frac0 - (frac - frac0)) / (frac - frac0), user_data)) failed = 1;
        }
    }
    lensrt_free(r->ctx, scratch);
    free_vertices(r->ctx, &cv);
    if (failed) return lensrt_fail(r->ctx, LENSRT_ERROR_CANCELLED, "cells: cancelled");
    return LENSRT_SUCCESS;
}
