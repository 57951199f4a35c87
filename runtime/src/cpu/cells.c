/* The CPU device's cells integrator (core/cells.h): per wavelength, the mesh vertices'
 * rows, phases, amplitudes and clip levels before the stop (in parallel over vertices),
 * then per pixel the transport after the stop at every vertex and the closed-form
 * integral over every triangle, cut where a clip crosses it. Pixels go in blocks of
 * LENSRT_CELLS_LANES (in parallel over blocks): the triangles of a block's pixels are
 * integrated together, one vector across the pixels (cpu/cells_kernel.c), and each
 * pixel's field is the sum of its own triangles in their order, the bits it has alone.
 *
 * Everything is in double. The pixel's terms are the Monte Carlo kernel's own
 * (lensrt_cpu_setup_pixel: pruned to the render's phase tolerance, in the window's
 * basis), so both integrators integrate the same function. */
#include "pass.h"

#include "cells_kernel.h"
#include "../lens/lens.h"

#include <math.h>
#include <stdint.h>
#include <string.h>
#ifdef LENSRT_OPENMP
#include <omp.h>
#endif

/* The calling thread's index in its OpenMP team (0 without OpenMP). */
static int thread_id(void)
{
#ifdef LENSRT_OPENMP
    return omp_get_thread_num();
#else
    return 0;
#endif
}

/* Log amplitudes below this (amplitude 0: intensity 0 or no transmittance) are held
 * there: e^-80 is 2e-35 of a unit amplitude, nothing in a float image. */
#define LOG_AMP_FLOOR (-80.0)

/* One wavelength's vertex data: rows [row][v] (structure of arrays, so that the
 * per-pixel sums over vertices vectorise); per light l the phase in waves (sph), the
 * amplitude (samp) and its log (lna), and the levels before the stop
 * (lev_o [l][v][1 + LENSRT_MAX_CLIP_PAIRS]). */
typedef struct cells_vertices {
    int n, n_rows, n_lev_o;
    double *rows, *sph, *samp, *lna, *lev_o;
} cells_vertices;

static void free_vertices(lensrt_context ctx, cells_vertices *cv)
{
    lensrt_free(ctx, cv->rows);
    lensrt_free(ctx, cv->sph);
    lensrt_free(ctx, cv->samp);
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
    cv->sph = lensrt_calloc(r->ctx, nv * nl, sizeof(double));
    cv->samp = lensrt_calloc(r->ctx, nv * nl, sizeof(double));
    cv->lna = lensrt_calloc(r->ctx, nv * nl, sizeof(double));
    cv->lev_o = lensrt_calloc(r->ctx, nv * nl * (1 + LENSRT_MAX_CLIP_PAIRS), sizeof(double));
    if (!cv->rows || !cv->sph || !cv->samp || !cv->lna || !cv->lev_o) {
        free_vertices(r->ctx, cv);
        return 0;
    }
    return 1;
}

/* Vertex v: the lens kind's rows (in double), and per light the wave at the stop. The
 * phase is kept unreduced: the triangles need its differences (each pixel subtracts
 * its vertex 0's, so that it stays a few thousand waves at most). */
static void prepare_vertex(const lensrt_render r, int w, const lensrt_mesh *m, cells_vertices *cv, long v, float *rf)
{
    const lensrt_lens_ops *ops = r->lens_ops;
    const double lambda_mm = r->wavelengths[w] / LENSRT_NM_PER_MM;
    const double x = m->xy[2 * v], y = m->xy[2 * v + 1];
    const int nr = r->n_rows;
    double mono[136];
    lensrt_rows rows;
    int l, k;
    // Rows in double straight into their columns, or in float (as the lens kind keeps
    // them) through the thread's scratch
    rows.stride = r->double_rows ? (size_t)cv->n : 1;
    rows.d = cv->rows + v;
    rows.f = rf;
    ops->sample_rows(r, w, x, y, mono, &rows);
    if (!r->double_rows)
        for (k = 0; k < nr; k++) cv->rows[(size_t)k * (size_t)cv->n + (size_t)v] = (double)rf[k];
    for (l = 0; l < r->n_lights; l++) {
        const size_t at = (size_t)l * (size_t)cv->n + (size_t)v;
        double amp = sqrt(r->lights[l].intensity), opl = 0.0;
        int n_lev = 0;
        if (ops->sample_levels) n_lev = ops->sample_levels(r, w, l, mono, &amp, &opl, cv->lev_o + at * (1 + LENSRT_MAX_CLIP_PAIRS));
        else ops->sample_wave(r, w, l, x, y, mono, &amp, &opl);
        if (v == 0) cv->n_lev_o = n_lev; /* the same at every vertex: one writer */
        cv->sph[at] = opl / lambda_mm;
        cv->samp[at] = amp > 0.0 ? amp : 0.0;
        cv->lna[at] = amp > 0.0 ? fmax(log(amp), LOG_AMP_FLOOR) : LOG_AMP_FLOOR;
    }
}

/* Scratch for one pixel of a block: per vertex the pixel's phase (waves), transmittance
 * amplitude and its log, the levels after the stop (lev_p) and, per light, all levels
 * (lev) and whether every one is >= 0 (in); hx, hy: room for the clips' positions. The
 * phasors go straight to the block's interleaved arrays (cells_block). */
typedef struct cells_scratch {
    double *ph, *lnt, *st, *lev_p, *hx, *hy, *lev;
    unsigned char *in;
} cells_scratch;

#define MAX_LEV_P (1 + LENSRT_MAX_CLIP_PAIRS)

/* Triangles per chunk of a block's pass (whole strips; a longer strip is a chunk alone):
 * 512 x 8 pixels x 3 doubles, 96 kB, stay in cache between the chunk's three loops. */
#define CELLS_CHUNK 512

/* A level of x^2 + y^2 <= r2: (r2 - x^2 - y^2) / (2 sqrt(r2)), mm-like near its zero. */
static double disc_level(double r2, double x, double y)
{
    return (r2 - (x * x + y * y)) / (2.0 * (r2 > 0.0 ? sqrt(r2) : 1.0));
}

/* out[v] = sum of the terms' coefficients times their rows, over every vertex. */
static void sum_terms(const lensrt_terms_d *t, const double *rows, int nv, double *out)
{
    int k, v;
    for (v = 0; v < nv; v++) out[v] = 0.0;
    for (k = 0; k < t->n; k++) {
        const double c = t->coef[k], *row = rows + (size_t)t->slot[k] * (size_t)nv;
        for (v = 0; v < nv; v++) out[v] += c * row[v];
    }
}

/* A pixel's set-up, shared by the meshes of one call: the Monte Carlo kernel's terms
 * (polynomial transport; lensrt_cpu_setup_pixel) or nothing (free space). */
typedef struct cells_pixel {
    lensrt_cpu_pixel px;
    lensrt_cpu_clip clip;
    double x, y, amp;
    int live;
} cells_pixel;

static void setup_pixel(lensrt_render r, int w, long p, cells_pixel *cp)
{
    cp->x = r->xs[p % r->width];
    cp->y = r->ys[p / r->width];
    cp->amp = 1.0;
    cp->live = 1;
    if (r->lens_ops->transport == LENSRT_TRANSPORT_FREE_SPACE) return;
    cp->live = lensrt_cpu_setup_pixel(r, w, cp->x, cp->y, &cp->px, r->clip_s ? &cp->clip : NULL);
    cp->amp = cp->px.amp;
}

/* The pixel's part at every vertex: phase in waves, log transmittance (and the free-space
 * kernel's log amplitude), the levels after the stop. Returns their count. */
static int pixel_vertices(lensrt_render r, int w, const cells_pixel *cp, const cells_vertices *cv, cells_scratch *s)
{
    const int nv = cv->n;
    int v, n_lev = 0;
    if (r->lens_ops->transport == LENSRT_TRANSPORT_FREE_SPACE) {
        // Rayleigh-Sommerfeld: the distance in waves and cos(theta) / (lambda r)
        const lensrt_analytic_lens *mdl = &r->lens->model;
        const double z = mdl->sensor_distance_mm + r->desc.sensor.focus_offset_mm;
        const double lambda_mm = r->wavelengths[w] / LENSRT_NM_PER_MM;
        const double *ax = cv->rows, *ay = cv->rows + nv;
        for (v = 0; v < nv; v++) {
            const double dx = cp->x - ax[v], dy = cp->y - ay[v], r2 = dx * dx + dy * dy + z * z;
            s->ph[v] = sqrt(r2) / lambda_mm;
            s->st[v] = z / (lambda_mm * r2);
            s->lnt[v] = log(s->st[v]);
        }
        return 0;
    }
    {
        const lensrt_pixel_d *d = &cp->px.d;
        double *hx = s->hx, *hy = s->hy;
        int q, j = 0;
        n_lev = (d->clip ? 1 : 0) + d->n_clip;
        sum_terms(&d->phase, cv->rows, nv, s->ph);
        if (d->tau.n > 0) {
            sum_terms(&d->tau, cv->rows, nv, s->st);
            lensrt_cells_log_amplitude(nv, s->st, s->lnt, LOG_AMP_FLOOR);
        } else {
            for (v = 0; v < nv; v++) {
                s->lnt[v] = 0.0;
                s->st[v] = 1.0;
            }
        }
        // The levels after the stop: the inner pupil, then the P_clip pairs
        if (d->clip) {
            sum_terms(&d->xi, cv->rows, nv, hx);
            sum_terms(&d->yi, cv->rows, nv, hy);
            for (v = 0; v < nv; v++) s->lev_p[(size_t)v * MAX_LEV_P + j] = disc_level(d->housing2, hx[v], hy[v]);
            j++;
        }
        for (q = 0; q < d->n_clip; q++, j++) {
            sum_terms(&d->clip_x[q], cv->rows, nv, hx);
            sum_terms(&d->clip_y[q], cv->rows, nv, hy);
            for (v = 0; v < nv; v++) {
                double e = disc_level(d->clip_r2[q], hx[v], hy[v]);
                if (d->clip_shaped[q]) {
                    const double f = lensrt_stop_shape_level(d->stop, hx[v], hy[v]);
                    if (f < e) e = f;
                }
                s->lev_p[(size_t)v * MAX_LEV_P + j] = e;
            }
        }
    }
    return n_lev;
}

/* A thread's scratch for a block of LENSRT_CELLS_LANES pixels: each pixel's own arrays
 * (its vertices and levels, for the scalar pass), then the block's values interleaved
 * for the vectorised triangles ([v * LANES + k], [t * LANES + k]). */
typedef struct cells_block {
    cells_scratch s[LENSRT_CELLS_LANES];
    double *zr, *zi, *er, *ei, *in, *cr, *ci, *rest;
} cells_block;

/* The fields of a block's nl pixels for every light: U[2 (k n_lights + l) + re/im]. Per
 * light, each pixel's vertex phasors and clip levels, then the triangles whose nodes
 * are apart inside every clip for all the block's pixels at once, then per pixel the
 * rest (close nodes: series; crossed by a clip: cut) one by one; each pixel adds its
 * triangles' integrals in their order, as one pixel alone would. */
static void integrate_block(lensrt_render r, int w, const cells_pixel *cp, int nl, const lensrt_mesh *m,
                            const cells_vertices *cv, cells_block *b, double *U)
{
    const int nv = cv->n, nt = m->n_triangles, n_lev_o = cv->n_lev_o, L = LENSRT_CELLS_LANES;
    int n_lev[LENSRT_CELLS_LANES], k, l, v, t, s0, s1;
    double acc_r[LENSRT_CELLS_LANES], acc_i[LENSRT_CELLS_LANES];
    for (k = 0; k < nl; k++) {
        for (l = 0; l < r->n_lights; l++) U[2 * (k * r->n_lights + l)] = U[2 * (k * r->n_lights + l) + 1] = 0.0;
        n_lev[k] = cp[k].live ? n_lev_o + pixel_vertices(r, w, &cp[k], cv, &b->s[k]) : 0;
    }
    for (l = 0; l < r->n_lights; l++) {
        const size_t off = (size_t)l * (size_t)nv;
        const double *lev_o = cv->lev_o + off * (1 + LENSRT_MAX_CLIP_PAIRS);
        if (r->lights[l].intensity <= 0.0) continue;
        for (k = 0; k < L; k++) {
            cells_scratch *s = &b->s[k];
            if (k >= nl || !cp[k].live) {
                // No pixel here (or a dark one): nothing apart, and its rest is skipped
                for (v = 0; v < nv; v++) {
                    const size_t at = (size_t)v * L + (size_t)k;
                    b->zr[at] = b->zi[at] = b->er[at] = b->ei[at] = b->in[at] = 0.0;
                }
                continue;
            }
            lensrt_cells_vertices(nv, s->ph, cv->sph + off, s->ph[0] + cv->sph[off], cv->lna + off, cv->samp + off,
                                  s->lnt, s->st, b->zr + k, b->zi + k, b->er + k, b->ei + k, (size_t)L);
            // The levels before the stop (this light's) and after it (this pixel's)
            // (level by level over the vertices: loops that run along them)
            memset(s->in, 1, (size_t)nv);
            {
                const int nlk = n_lev[k];
                int j;
                for (j = 0; j < nlk; j++) {
                    const double *src = j < n_lev_o ? lev_o + j : s->lev_p + (j - n_lev_o);
                    const size_t stride = j < n_lev_o ? 1 + LENSRT_MAX_CLIP_PAIRS : MAX_LEV_P;
                    for (v = 0; v < nv; v++) {
                        const double x = src[(size_t)v * stride];
                        s->lev[(size_t)v * nlk + j] = x;
                        s->in[v] &= (unsigned char)(x >= 0.0);
                    }
                }
            }
            for (v = 0; v < nv; v++) b->in[(size_t)v * L + (size_t)k] = s->in[v] ? 1.0 : 0.0;
        }
        // The triangles in chunks of whole strips of about CELLS_CHUNK (their values stay in
        // cache): the vectorised ones, then the rest pixel by pixel in place (a dark
        // pixel's stay 0; a triangle whose nodes are apart for the whole block, rest 0.0
        // in every lane, all bits zero, is passed over at once), then each pixel's sum in
        // the triangles' order (all the block's at once)
        for (k = 0; k < L; k++) acc_r[k] = acc_i[k] = 0.0;
        for (s0 = 0; s0 < m->n_strips; s0 = s1) {
            const int ta = m->strip[5 * s0];
            int tb;
            for (s1 = s0 + 1; s1 < m->n_strips && m->strip[5 * s1] + m->strip[5 * s1 + 1] - ta <= CELLS_CHUNK; s1++) {
            }
            tb = s1 < m->n_strips ? m->strip[5 * s1] : nt;
            lensrt_cells_triangles(m, s0, s1, b->zr, b->zi, b->er, b->ei, b->in, b->cr, b->ci, b->rest);
            for (t = ta; t < tb; t++) {
                uint64_t bits[LENSRT_CELLS_LANES], any = 0;
                memcpy(bits, b->rest + (size_t)(t - ta) * L, sizeof bits);
                for (k = 0; k < L; k++) any |= bits[k];
                if (!any) continue;
                for (k = 0; k < nl; k++) {
                    const size_t at = (size_t)(t - ta) * L + (size_t)k;
                    const cells_scratch *s = &b->s[k];
                    const int *tv = m->tri + 3 * t, nlv = n_lev[k];
                    double z[6], E[6], lev[3 * LENSRT_CELLS_MAX_LEVELS], o[2] = {0.0, 0.0};
                    int q, j;
                    if (b->rest[at] == 0.0 || !cp[k].live) continue;
                    for (q = 0; q < 3; q++) {
                        const size_t vq = (size_t)tv[q] * L + (size_t)k;
                        z[2 * q] = b->zr[vq];
                        z[2 * q + 1] = b->zi[vq];
                        E[2 * q] = b->er[vq];
                        E[2 * q + 1] = b->ei[vq];
                        for (j = 0; j < nlv; j++) lev[q * nlv + j] = s->lev[(size_t)tv[q] * nlv + j];
                    }
                    // Inside every clip: the closed form with its series; else cut
                    if (nlv == 0 || (s->in[tv[0]] && s->in[tv[1]] && s->in[tv[2]])) lensrt_tri_integral(m->area[t], z, E, o);
                    else lensrt_tri_integral_clipped(m->area[t], z, E, lev, nlv, o);
                    b->cr[at] = o[0];
                    b->ci[at] = o[1];
                }
            }
            for (t = 0; t < tb - ta; t++)
                for (k = 0; k < L; k++) {
                    acc_r[k] += b->cr[(size_t)t * L + (size_t)k];
                    acc_i[k] += b->ci[(size_t)t * L + (size_t)k];
                }
        }
        for (k = 0; k < nl; k++) {
            if (!cp[k].live) continue; /* dark */
            U[2 * (k * r->n_lights + l)] = cp[k].amp * acc_r[k];
            U[2 * (k * r->n_lights + l) + 1] = cp[k].amp * acc_i[k];
        }
    }
}

/* Scratch of one thread for a block on meshes of up to nv vertices, in chunks of up to nt
 * triangles. */
static size_t scratch_size(size_t nv, size_t nt)
{
    /* per pixel: ph, lnt, st, hx, hy (nv each), lev_p (MAX_LEV_P nv), lev (MAX_LEVELS
     * nv), in (nv bytes); the block: zr, zi, er, ei, in (LANES nv each), a chunk's cr,
     * ci, rest (LANES nt each) */
    const size_t L = LENSRT_CELLS_LANES;
    return L * nv * (6 + MAX_LEV_P + LENSRT_CELLS_MAX_LEVELS) + L * (5 * nv + 3 * nt);
}

static void block_view(double *base, size_t nv, size_t nt, cells_block *b)
{
    const size_t L = LENSRT_CELLS_LANES, per = nv * (6 + MAX_LEV_P + LENSRT_CELLS_MAX_LEVELS);
    size_t k;
    for (k = 0; k < L; k++) {
        cells_scratch *s = &b->s[k];
        double *p = base + k * per;
        s->ph = p;
        s->lnt = p + nv;
        s->st = p + 2 * nv;
        s->hx = p + 3 * nv;
        s->hy = p + 4 * nv;
        s->lev_p = p + 5 * nv;
        s->lev = p + (5 + MAX_LEV_P) * nv;
        s->in = (unsigned char *)(p + (5 + MAX_LEV_P + LENSRT_CELLS_MAX_LEVELS) * nv);
    }
    base += L * per;
    b->zr = base;
    b->zi = base + L * nv;
    b->er = base + 2 * L * nv;
    b->ei = base + 3 * L * nv;
    b->in = base + 4 * L * nv;
    b->cr = base + 5 * L * nv;
    b->ci = b->cr + L * nt;
    b->rest = b->ci + L * nt;
}

/* The block of nl pixels pix[] of wavelength w on every mesh: one set-up per pixel, then
 * each mesh's fields into its U. */
static void cells_block_all(lensrt_render r, int w, const long *pix, int nl, const lensrt_cells_job *job,
                            const cells_vertices *cv, double *base, size_t nv_max, size_t nt_chunk)
{
    const size_t npix = (size_t)r->width * (size_t)r->height;
    cells_pixel cp[LENSRT_CELLS_LANES];
    cells_block b;
    double f[2 * LENSRT_CELLS_LANES * LENSRT_MAX_LIGHTS];
    int k, q, l;
    for (k = 0; k < nl; k++) setup_pixel(r, w, pix[k], &cp[k]);
    block_view(base, nv_max, nt_chunk, &b);
    for (q = 0; q < job->n_mesh; q++) {
        integrate_block(r, w, cp, nl, job->mesh[q], &cv[q], &b, f);
        for (k = 0; k < nl; k++)
            for (l = 0; l < r->n_lights; l++) {
                const size_t at = ((size_t)l * (size_t)r->n_wl + (size_t)w) * npix + (size_t)pix[k];
                job->U[q][2 * at] = f[2 * (k * r->n_lights + l)];
                job->U[q][2 * at + 1] = f[2 * (k * r->n_lights + l) + 1];
            }
    }
}

/* What a call needs beyond the job: each mesh's vertex data (for one wavelength at a
 * time), and the threads' scratch. */
typedef struct cells_state {
    cells_vertices cv[LENSRT_CELLS_MAX_MESHES];
    double *scratch;
    float *rows_f;
    size_t nv_max, nt_chunk, per_thread;
    int nthreads;
} cells_state;

static void free_state(lensrt_render r, cells_state *st, int n_mesh)
{
    int k;
    for (k = 0; k < n_mesh; k++) free_vertices(r->ctx, &st->cv[k]);
    lensrt_free(r->ctx, st->scratch);
    lensrt_free(r->ctx, st->rows_f);
}

static int alloc_state(lensrt_render r, const lensrt_cells_job *job, int nthreads, cells_state *st)
{
    int k, ok = 1;
    memset(st, 0, sizeof *st);
    st->nthreads = nthreads;
    for (k = 0; k < job->n_mesh; k++) {
        ok &= alloc_vertices(r, job->mesh[k], &st->cv[k]);
        if ((size_t)job->mesh[k]->n_vertices > st->nv_max) st->nv_max = (size_t)job->mesh[k]->n_vertices;
        // A chunk's triangles: CELLS_CHUNK, or a longer strip alone
        {
            const lensrt_mesh *m = job->mesh[k];
            int s;
            if (st->nt_chunk < CELLS_CHUNK) st->nt_chunk = CELLS_CHUNK;
            for (s = 0; s < m->n_strips; s++)
                if ((size_t)m->strip[5 * s + 1] > st->nt_chunk) st->nt_chunk = (size_t)m->strip[5 * s + 1];
        }
    }
    st->per_thread = scratch_size(st->nv_max, st->nt_chunk);
    st->scratch = lensrt_calloc(r->ctx, st->per_thread * (size_t)nthreads, sizeof(double));
    st->rows_f = lensrt_calloc(r->ctx, (size_t)nthreads * (size_t)(r->n_rows > 0 ? r->n_rows : 1), sizeof(float));
    if (!ok || !st->scratch || !st->rows_f) {
        free_state(r, st, job->n_mesh);
        return 0;
    }
    return 1;
}

/* Every mesh's vertices for wavelength w (threaded: OpenMP over vertices). */
static void prepare_meshes(lensrt_render r, int w, const lensrt_cells_job *job, cells_state *st, int threaded)
{
    int k;
    for (k = 0; k < job->n_mesh; k++) {
        const long nv = job->mesh[k]->n_vertices;
        long v;
        if (!threaded) {
            for (v = 0; v < nv; v++) prepare_vertex(r, w, job->mesh[k], &st->cv[k], v, st->rows_f);
            continue;
        }
#ifdef LENSRT_OPENMP
#pragma omp parallel for schedule(static) num_threads(st->nthreads)
#endif
        for (v = 0; v < nv; v++) {
            const int th = thread_id();
            prepare_vertex(r, w, job->mesh[k], &st->cv[k], v, st->rows_f + (size_t)th * (size_t)r->n_rows);
        }
    }
}

lensrt_result lensrt_cpu_cells(lensrt_render r, const lensrt_cells_job *job, lensrt_progress_fn progress,
                               void *user_data)
{
    const long npix = (long)r->width * r->height;
    const int nthreads =
#ifdef LENSRT_OPENMP
        r->ctx->threads > 0 ? r->ctx->threads : omp_get_max_threads();
#else
        1;
#endif
    cells_state st;
    double t0 = lensrt_seconds();
    int w, failed = 0;
    if (!alloc_state(r, job, nthreads, &st))
        return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "cells: out of memory for %d threads' scratch", nthreads);
    for (w = 0; w < r->n_wl && !failed; w++) {
        const long n_blocks = (npix + LENSRT_CELLS_LANES - 1) / LENSRT_CELLS_LANES;
        long blk;
        prepare_meshes(r, w, job, &st, 1);
        // Every block of LANES pixels, in parallel over blocks (each writes only its own
        // pixels' fields)
#ifdef LENSRT_OPENMP
#pragma omp parallel for schedule(dynamic, 1) num_threads(nthreads)
#endif
        for (blk = 0; blk < n_blocks; blk++) {
            const int th = thread_id();
            long pix[LENSRT_CELLS_LANES];
            int k, nl = 0;
            for (k = 0; k < LENSRT_CELLS_LANES && blk * LENSRT_CELLS_LANES + k < npix; k++)
                pix[nl++] = blk * LENSRT_CELLS_LANES + k;
            cells_block_all(r, w, pix, nl, job, st.cv, st.scratch + st.per_thread * (size_t)th, st.nv_max, st.nt_chunk);
        }
        if (progress) {
            const double frac = (double)(w + 1) / r->n_wl, el = lensrt_seconds() - t0;
            if (progress(frac, el * (1.0 - frac) / frac, user_data)) failed = 1;
        }
    }
    free_state(r, &st, job->n_mesh);
    if (failed) return lensrt_fail(r->ctx, LENSRT_ERROR_CANCELLED, "cells: cancelled");
    return LENSRT_SUCCESS;
}

lensrt_result lensrt_cpu_cells_tile(lensrt_render r, const lensrt_cells_job *job, int x0, int y0, int width, int height)
{
    cells_state st;
    int w, x, y;
    if (!alloc_state(r, job, 1, &st)) return LENSRT_ERROR_OUT_OF_MEMORY;
    for (w = 0; w < r->n_wl; w++) {
        long pix[LENSRT_CELLS_LANES];
        int nl = 0;
        prepare_meshes(r, w, job, &st, 0);
        // The rectangle's pixels in blocks of LANES (a pixel's field does not depend on
        // the others in its block)
        for (y = y0; y < y0 + height; y++)
            for (x = x0; x < x0 + width; x++) {
                pix[nl++] = (long)y * r->width + x;
                if (nl == LENSRT_CELLS_LANES || (y == y0 + height - 1 && x == x0 + width - 1)) {
                    cells_block_all(r, w, pix, nl, job, st.cv, st.scratch, st.nv_max, st.nt_chunk);
                    nl = 0;
                }
            }
    }
    free_state(r, &st, job->n_mesh);
    return LENSRT_SUCCESS;
}
