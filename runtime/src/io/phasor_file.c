/* Phasor sums on disk: save, load (resume) and merge. Sums add, so renders of the same
 * scene made apart (other seeds, other machines) combine into one.
 *
 * Format `lensrt-phasors 2`, native byte order (checked by a marker):
 *   magic[16] "lensrt-phasors\n\0", u32 version, u32 byte-order marker 0x01020304,
 *   u64 scene hash, u64 seed, u64 samples per wavelength, u64 splats, f64 seconds,
 *   i32 width, height, wavelengths, lights, has_sum_of_squares, runs, u64 checksum,
 *   u64 runs[runs][3] ({seed, first, end} of the sample indices the sums hold),
 *   f64 sums[2 * lights * wavelengths * pixels], f64 sums of squares[...] (if present);
 *   sums[((l * wavelengths + w) * pixels + p) * 2 + (0 re, 1 im)], p = y * width + x
 *   (row 0 at the top, +y), sums of squares likewise without the pair. What a sum is
 *   and its phase reference (per grid point, the stop-centre ray's rear path for fitted
 *   lenses): lensrt.h, above lensrt_render_save.
 * "pixels", width and height are the render's grid points (core/render.h): with the box
 * pixel filter each pixel's sx x sy sub-pixel points (since 0.8.0), so sums of renders
 * whose filter or samples per pixel differ are refused as another grid, with a message
 * that says so; the grid's pitch is in the scene hash.
 * The scene hash covers the lens's coefficients, domains and constants (not only its
 * name); the checksum is FNV-1a 64 over the whole file with the checksum field zero.
 * A reader refuses: another version, a checksum mismatch, a count that disagrees with
 * the runs, no samples or more than 2^53, sums that are not finite, negative sums of
 * squares; merge refuses a file whose runs overlap the render's (samples counted twice).
 * Version 1 files (no checksum, name-only hash) are refused: render them again. */
#include "../core/render.h"
#include "../core/tiles.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "image_io.h"

#define MAGIC "lensrt-phasors\n"
#define VERSION 2u
#define MARKER 0x01020304u
#define MAX_RUNS 64
#define MAX_SAMPLES 9007199254740992ULL /* 2^53: beyond, sample counts are not exact doubles */
#define FNV_START 0xcbf29ce484222325ULL

typedef struct file_header {
    char magic[16];
    uint32_t version, marker;
    uint64_t scene, seed, samples, splats;
    double seconds;
    int32_t width, height, n_wl, n_lights, has_sumsq, n_runs;
    uint64_t checksum;
} file_header;

/* FNV-1a over everything that decides what a phasor sum means. */
static uint64_t fnv(uint64_t h, const void *data, size_t n)
{
    const unsigned char *p = data;
    size_t i;
    for (i = 0; i < n; i++) h = (h ^ p[i]) * 0x100000001b3ULL;
    return h;
}

/* The content of a fitted system: domains, transforms, exponents, coefficients. */
static uint64_t system_hash(uint64_t h, const lensrt_system *s)
{
    int i;
    h = fnv(h, &s->n_inputs, sizeof s->n_inputs);
    h = fnv(h, &s->n_outputs, sizeof s->n_outputs);
    for (i = 0; i < s->n_inputs && i < 8; i++) {
        const lensrt_input *in = &s->inputs[i];
        double v[4];
        v[0] = in->lo;
        v[1] = in->hi;
        v[2] = in->c;
        v[3] = in->s;
        h = fnv(h, v, sizeof v);
        h = fnv(h, &in->transform, sizeof in->transform);
    }
    for (i = 0; i < s->n_outputs && i < 8; i++) {
        const lensrt_poly *p = &s->outputs[i];
        h = fnv(h, &p->n_terms, sizeof p->n_terms);
        if (p->n_terms > 0 && p->exponents)
            h = fnv(h, p->exponents, (size_t)p->n_terms * (size_t)s->n_inputs);
        if (p->n_terms > 0 && p->coefficients)
            h = fnv(h, p->coefficients, sizeof(double) * (size_t)p->n_terms);
    }
    return h;
}

/* The lens: name, constants and (fitted) both systems' content, or (analytic) its model. */
static uint64_t lens_hash(uint64_t h, const lensrt_lens_s *l)
{
    double v[8];
    h = fnv(h, l->name, strlen(l->name));
    v[0] = l->focal_length_mm;
    v[1] = l->stop_radius_max_mm;
    v[2] = l->stop_radius_f1_mm;
    v[3] = l->sensor_defocus_mm;
    v[4] = l->squeeze;
    v[5] = l->analytic ? l->model.focal_length_mm : 0.0;
    v[6] = l->analytic ? l->model.sensor_distance_mm : 0.0;
    v[7] = l->analytic ? (double)l->model.one_dimensional : 0.0;
    h = fnv(h, v, sizeof v);
    if (!l->analytic) {
        h = system_hash(h, &l->p_o);
        h = system_hash(h, &l->p_s);
        /* a ghost's clip system (absent in direct tables, whose hash is unchanged) */
        if (l->p_clip.n_outputs) h = system_hash(h, &l->p_clip);
    }
    return h;
}

static uint64_t scene_hash(const lensrt_render r)
{
    uint64_t h = FNV_START;
    const lensrt_aperture *a = &r->desc.aperture;
    int i, shape = (int)a->shape, precision = (int)r->desc.precision;
    double v[12];
    h = lens_hash(h, r->lens);
    h = fnv(h, r->wavelengths, sizeof(double) * (size_t)r->n_wl);
    for (i = 0; i < r->n_lights; i++) {
        // The light as P_o sees it (direction cosines towards it), not its field angles:
        // files written before the field angles took the designers' sign (issue 15) hold
        // the mirrored light under the same angles, and are refused as another scene
        v[0] = r->light_x[i];
        v[1] = r->light_y[i];
        v[2] = r->lights[i].distance_mm;
        v[3] = r->lights[i].intensity;
        h = fnv(h, v, sizeof(double) * 4);
    }
    v[0] = r->stop_radius;
    v[1] = r->desc.sensor.focus_offset_mm;
    v[2] = r->pitch_x;
    v[3] = r->pitch_y;
    v[4] = r->desc.sensor.center_x_mm;
    v[5] = r->desc.sensor.center_y_mm;
    v[6] = a->blade_curvature;
    v[7] = a->rotation_deg;
    v[8] = a->slit_width_mm;
    v[9] = a->slit_separation_mm;
    v[10] = (double)a->blades;
    v[11] = r->desc.phase_tolerance_waves;
    h = fnv(h, v, sizeof v);
    h = fnv(h, &shape, sizeof shape);
    h = fnv(h, &precision, sizeof precision);
    return h;
}

static size_t n_sums(const lensrt_render r)
{
    return (size_t)r->n_lights * (size_t)r->n_wl * (size_t)r->width * (size_t)r->height;
}

/* Record the samples run() added since the last record: desc.seed, indices
 * [runs_samples, samples). 0 when the record is full. */
static int record_own(lensrt_render r)
{
    uint64_t *last = r->n_runs > 0 ? r->runs[r->n_runs - 1] : NULL;
    if (r->samples <= r->runs_samples)
        return 1;
    if (last && last[0] == r->desc.seed && last[2] == r->runs_samples)
        last[2] = r->samples; /* the same sequence, continued */
    else if (r->n_runs < MAX_RUNS) {
        r->runs[r->n_runs][0] = r->desc.seed;
        r->runs[r->n_runs][1] = r->runs_samples;
        r->runs[r->n_runs][2] = r->samples;
        r->n_runs++;
    } else
        return 0;
    r->runs_samples = r->samples;
    return 1;
}

static lensrt_result too_many_runs(lensrt_render r, const char *path)
{
    return lensrt_fail(r->ctx, LENSRT_ERROR_INCOMPATIBLE,
                       "%s: the sums would come from more than %d separate sample runs (seeds or "
                       "sequences), which a phasor file cannot record; merge fewer files", path, MAX_RUNS);
}

lensrt_result lensrt_render_save(lensrt_render r, const char *path)
{
    file_header hd;
    char *tmp = NULL;
    const char *refusal;
    FILE *f;
    size_t n;
    uint64_t sum = FNV_START;
    int ok, err = 0;
    lensrt_result res;
    if (!r || !path) return LENSRT_ERROR_INVALID_ARGUMENT;
    if ((res = lensrt_tiles_idle(r, "save")) != LENSRT_SUCCESS || (res = lensrt_cells_idle(r, "save")) != LENSRT_SUCCESS)
        return res;
    if (!record_own(r)) return too_many_runs(r, path);
    if ((refusal = lensrt_target_refusal(path)) != NULL)
        return lensrt_fail(r->ctx, LENSRT_ERROR_IO, "%s: cannot write phasor sums: it %s", path, refusal);
    n = n_sums(r);
    memset(&hd, 0, sizeof hd);
    memcpy(hd.magic, MAGIC, sizeof MAGIC);
    hd.version = VERSION;
    hd.marker = MARKER;
    hd.scene = scene_hash(r);
    hd.seed = r->desc.seed;
    hd.samples = r->samples;
    hd.splats = r->splats;
    hd.seconds = r->seconds;
    hd.width = r->width;
    hd.height = r->height;
    hd.n_wl = r->n_wl;
    hd.n_lights = r->n_lights;
    hd.has_sumsq = r->sumsq != NULL;
    hd.n_runs = r->n_runs;
    // The checksum: the header with a zero checksum field, then everything after it
    sum = fnv(sum, &hd, sizeof hd);
    sum = fnv(sum, r->runs, sizeof(uint64_t) * 3 * (size_t)r->n_runs);
    sum = fnv(sum, r->sum, sizeof(double) * 2 * n);
    if (r->sumsq) sum = fnv(sum, r->sumsq, sizeof(double) * n);
    hd.checksum = sum;
    // Write a temporary file next to the target, flush it to disk, rename it over the target
    f = lensrt_fopen_temporary(&r->ctx->allocator, path, &tmp, &err);
    if (!f) {
        return lensrt_fail(r->ctx, err == ENOMEM ? LENSRT_ERROR_OUT_OF_MEMORY : LENSRT_ERROR_IO,
                           "%s: cannot write phasor sums: %s", path, strerror(err));
    }
    ok = fwrite(&hd, sizeof hd, 1, f) == 1 &&
         fwrite(r->runs, sizeof(uint64_t) * 3, (size_t)r->n_runs, f) == (size_t)r->n_runs &&
         fwrite(r->sum, sizeof(double), 2 * n, f) == 2 * n &&
         (!r->sumsq || fwrite(r->sumsq, sizeof(double), n, f) == n);
    ok = ok && fflush(f) == 0 && fsync(fileno(f)) == 0;
    if (!ok) err = errno;
    if (fclose(f) != 0 && ok) {
        ok = 0;
        err = errno;
    }
    if (ok && rename(tmp, path) != 0) {
        ok = 0;
        err = errno;
    }
    if (!ok) {
        remove(tmp);
        lensrt_free(r->ctx, tmp);
        return lensrt_fail(r->ctx, LENSRT_ERROR_IO, "%s: writing phasor sums failed: %s", path, strerror(err));
    }
    lensrt_free(r->ctx, tmp);
    return LENSRT_SUCCESS;
}

/* The file's runs, checked: at most MAX_RUNS, each non-empty, disjoint per seed, summing
 * to the header's sample count. NULL when fine, else what is wrong. */
static const char *check_runs(const file_header *hd, uint64_t runs[][3])
{
    uint64_t total = 0;
    int i, j;
    if (hd->samples == 0) return "holds no samples";
    if (hd->samples > MAX_SAMPLES) return "claims more than 2^53 samples per wavelength";
    for (i = 0; i < hd->n_runs; i++) {
        if (runs[i][2] <= runs[i][1] || runs[i][2] > MAX_SAMPLES) return "has an empty or impossible sample run";
        total += runs[i][2] - runs[i][1];
        for (j = 0; j < i; j++)
            if (runs[j][0] == runs[i][0] && runs[j][1] < runs[i][2] && runs[i][1] < runs[j][2])
                return "counts some samples twice (overlapping runs)";
    }
    if (total != hd->samples) return "has a sample count that disagrees with its runs";
    return NULL;
}

/* Read a phasor file that matches r's scene; sums go to new buffers, runs to `runs`. */
static lensrt_result read_file(lensrt_render r, const char *path, file_header *hd, uint64_t runs[][3], double **sum,
                               double **sumsq)
{
    FILE *f;
    size_t n = n_sums(r), i;
    uint64_t scene = scene_hash(r), check = FNV_START, stored;
    const char *bad = NULL;
    int ok;
    *sum = *sumsq = NULL;
    f = fopen(path, "rb");
    if (!f) return lensrt_fail(r->ctx, LENSRT_ERROR_IO, "%s: cannot open phasor sums: %s", path, strerror(errno));
    if (fread(hd, sizeof *hd, 1, f) != 1 || memcmp(hd->magic, MAGIC, sizeof MAGIC) != 0 || hd->marker != MARKER) {
        fclose(f);
        return lensrt_fail(r->ctx, LENSRT_ERROR_PARSE, "%s: not a lensrt-phasors file of this byte order", path);
    }
    if (hd->version != VERSION) {
        fclose(f);
        return lensrt_fail(r->ctx, LENSRT_ERROR_PARSE,
                           "%s: lensrt-phasors version %u; this lensrt reads version %u only (checksummed, with "
                           "the lens's content in the scene hash): render the sums again to resume or merge them",
                           path, hd->version, VERSION);
    }
    if (hd->n_runs < 1 || hd->n_runs > MAX_RUNS) {
        fclose(f);
        return lensrt_fail(r->ctx, LENSRT_ERROR_PARSE, "%s: corrupted phasor sums (%d sample runs)", path, hd->n_runs);
    }
    if (hd->width != r->width || hd->height != r->height) {
        // The sums are the render's grid points' (core/render.h): pixels times the box
        // filter's sub-pixel points per axis
        fclose(f);
        return lensrt_fail(r->ctx, LENSRT_ERROR_INCOMPATIBLE,
                           "%s: phasor sums of another scene (a grid of %d x %d points); the render has %d x %d "
                           "(%d x %d pixels of %d x %d points, the %s filter): the window, the pixel filter and its "
                           "samples per pixel must match (lensrt_render_get_stats says a render's)",
                           path, hd->width, hd->height, r->width, r->height, r->out_width, r->out_height, r->sx, r->sy,
                           r->pixel_filter == LENSRT_PIXEL_FILTER_POINT ? "point" : "box");
    }
    if (hd->n_wl != r->n_wl || hd->n_lights != r->n_lights || hd->scene != scene || hd->has_sumsq != (r->sumsq != NULL)) {
        fclose(f);
        return lensrt_fail(r->ctx, LENSRT_ERROR_INCOMPATIBLE,
                           "%s: phasor sums of another scene (%d x %d pixels, %d wavelengths, %d lights%s); "
                           "the render has %d x %d, %d, %d and must match in lens (its coefficients too), "
                           "lights, aperture, focus, window and estimator", path, hd->width, hd->height, hd->n_wl,
                           hd->n_lights, hd->scene != scene ? ", other settings" : "", r->width, r->height, r->n_wl,
                           r->n_lights);
    }
    *sum = lensrt_alloc(r->ctx, sizeof(double) * 2 * n);
    if (hd->has_sumsq) *sumsq = lensrt_alloc(r->ctx, sizeof(double) * n);
    if (!*sum || (hd->has_sumsq && !*sumsq)) {
        fclose(f);
        lensrt_free(r->ctx, *sum);
        lensrt_free(r->ctx, *sumsq);
        *sum = *sumsq = NULL;
        return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "%s: out of memory", path);
    }
    ok = fread(runs, sizeof(uint64_t) * 3, (size_t)hd->n_runs, f) == (size_t)hd->n_runs &&
         fread(*sum, sizeof(double), 2 * n, f) == 2 * n && (!hd->has_sumsq || fread(*sumsq, sizeof(double), n, f) == n);
    ok = ok && fgetc(f) == EOF;
    fclose(f);
    // The checksum over the header (checksum field zero) and the rest
    if (ok) {
        stored = hd->checksum;
        hd->checksum = 0;
        check = fnv(check, hd, sizeof *hd);
        hd->checksum = stored;
        check = fnv(check, runs, sizeof(uint64_t) * 3 * (size_t)hd->n_runs);
        check = fnv(check, *sum, sizeof(double) * 2 * n);
        if (hd->has_sumsq) check = fnv(check, *sumsq, sizeof(double) * n);
        if (check != stored) bad = "fails its checksum (the file is corrupted)";
    } else
        bad = "is truncated or oversized";
    // Counts and values: what the checksum cannot vouch for (a writer's own bug, a crafted file)
    if (!bad) bad = check_runs(hd, runs);
    if (!bad && !(isfinite(hd->seconds) && hd->seconds >= 0)) bad = "has an impossible render time";
    for (i = 0; !bad && i < 2 * n; i++)
        if (!isfinite((*sum)[i])) bad = "holds a sum that is not finite (NaN or inf)";
    for (i = 0; !bad && *sumsq && i < n; i++)
        if (!isfinite((*sumsq)[i]) || (*sumsq)[i] < 0) bad = "holds a sum of squares that is negative or not finite";
    if (bad) {
        lensrt_free(r->ctx, *sum);
        lensrt_free(r->ctx, *sumsq);
        *sum = *sumsq = NULL;
        return lensrt_fail(r->ctx, LENSRT_ERROR_PARSE, "%s: phasor sums refused: the file %s", path, bad);
    }
    return LENSRT_SUCCESS;
}

lensrt_result lensrt_render_load(lensrt_render r, const char *path)
{
    file_header hd;
    uint64_t runs[MAX_RUNS][3];
    double *sum, *sumsq;
    lensrt_result res;
    if (!r || !path) return LENSRT_ERROR_INVALID_ARGUMENT;
    if ((res = lensrt_tiles_idle(r, "load")) != LENSRT_SUCCESS || (res = lensrt_cells_idle(r, "load")) != LENSRT_SUCCESS)
        return res;
    if ((res = read_file(r, path, &hd, runs, &sum, &sumsq)) != LENSRT_SUCCESS) return res;
    // Replace the sums and their record; a later run() continues the saved sequence when the seed matches
    lensrt_free(r->ctx, r->sum);
    lensrt_free(r->ctx, r->sumsq);
    r->sum = sum;
    r->sumsq = sumsq;
    r->samples = hd.samples;
    lensrt_tail_forget(r);
    r->splats = hd.splats;
    r->seconds = hd.seconds;
    memcpy(r->runs, runs, sizeof(uint64_t) * 3 * (size_t)hd.n_runs);
    r->n_runs = hd.n_runs;
    r->runs_samples = hd.samples;
    if (hd.seed != r->desc.seed)
        lensrt_log(r->ctx, LENSRT_LOG_WARNING, "%s: saved with seed %llu, continuing with seed %llu", path,
                   (unsigned long long)hd.seed, (unsigned long long)r->desc.seed);
    return LENSRT_SUCCESS;
}

lensrt_result lensrt_render_merge(lensrt_render r, const char *path)
{
    file_header hd;
    uint64_t runs[MAX_RUNS][3];
    double *sum, *sumsq;
    lensrt_result res;
    size_t i, n;
    int a, b;
    if (!r || !path) return LENSRT_ERROR_INVALID_ARGUMENT;
    if ((res = lensrt_tiles_idle(r, "merge")) != LENSRT_SUCCESS || (res = lensrt_cells_idle(r, "merge")) != LENSRT_SUCCESS)
        return res;
    if (!record_own(r)) return too_many_runs(r, path);
    if ((res = read_file(r, path, &hd, runs, &sum, &sumsq)) != LENSRT_SUCCESS) return res;
    // Sample points are functions of (seed, index): a run of the same seed over indices
    // the render already holds would count those samples twice
    for (a = 0; a < hd.n_runs; a++)
        for (b = 0; b < r->n_runs; b++)
            if (runs[a][0] == r->runs[b][0] && runs[a][1] < r->runs[b][2] && r->runs[b][1] < runs[a][2]) {
                lensrt_free(r->ctx, sum);
                lensrt_free(r->ctx, sumsq);
                return lensrt_fail(r->ctx, LENSRT_ERROR_INCOMPATIBLE,
                                   "%s: holds samples %llu..%llu of the same seed %llu as this render's "
                                   "%llu..%llu, which would be counted twice; merge renders made with "
                                   "different seeds (or use load to resume)", path,
                                   (unsigned long long)runs[a][1], (unsigned long long)runs[a][2] - 1,
                                   (unsigned long long)runs[a][0], (unsigned long long)r->runs[b][1],
                                   (unsigned long long)r->runs[b][2] - 1);
            }
    if (r->n_runs + hd.n_runs > MAX_RUNS || r->samples + hd.samples > MAX_SAMPLES) {
        lensrt_free(r->ctx, sum);
        lensrt_free(r->ctx, sumsq);
        return too_many_runs(r, path);
    }
    n = n_sums(r);
    for (i = 0; i < 2 * n; i++) r->sum[i] += sum[i];
    for (i = 0; sumsq && i < n; i++) r->sumsq[i] += sumsq[i];
    memcpy(r->runs[r->n_runs], runs, sizeof(uint64_t) * 3 * (size_t)hd.n_runs);
    r->n_runs += hd.n_runs;
    r->samples += hd.samples;
    r->runs_samples = r->samples;
    lensrt_tail_forget(r);
    r->splats += hd.splats;
    r->seconds += hd.seconds;
    lensrt_free(r->ctx, sum);
    lensrt_free(r->ctx, sumsq);
    return LENSRT_SUCCESS;
}
