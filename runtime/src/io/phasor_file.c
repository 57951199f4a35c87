/* Phasor sums on disk: save, load (resume) and merge. Sums add, so renders of the same
 * scene made apart (other seeds, other machines) combine into one.
 *
 * Format `lensrt-phasors 1`, native byte order (checked by a marker):
 *   magic[16] "lensrt-phasors\n\0", u32 version, u32 byte-order marker 0x01020304,
 *   u64 scene hash, u64 seed, u64 samples per wavelength, u64 splats, f64 seconds,
 *   i32 width, height, wavelengths, lights, has_sum_of_squares, pad,
 *   f64 sums[2 * lights * wavelengths * pixels], f64 sums of squares[...] (if present). */
#include "../core/render.h"
#include "../core/tiles.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#define MAGIC "lensrt-phasors\n"
#define VERSION 1u
#define MARKER 0x01020304u

typedef struct file_header {
    char magic[16];
    uint32_t version, marker;
    uint64_t scene, seed, samples, splats;
    double seconds;
    int32_t width, height, n_wl, n_lights, has_sumsq, pad;
} file_header;

/* FNV-1a over everything that decides what a phasor sum means. */
static uint64_t fnv(uint64_t h, const void *data, size_t n)
{
    const unsigned char *p = data;
    size_t i;
    for (i = 0; i < n; i++) h = (h ^ p[i]) * 0x100000001b3ULL;
    return h;
}

static uint64_t scene_hash(const lensrt_render r)
{
    uint64_t h = 0xcbf29ce484222325ULL;
    const lensrt_aperture *a = &r->desc.aperture;
    int i, shape = (int)a->shape, precision = (int)r->desc.precision;
    double v[12];
    h = fnv(h, r->lens->name, strlen(r->lens->name));
    h = fnv(h, r->wavelengths, sizeof(double) * (size_t)r->n_wl);
    for (i = 0; i < r->n_lights; i++) {
        v[0] = r->lights[i].field_x_deg;
        v[1] = r->lights[i].field_y_deg;
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

lensrt_result lensrt_render_save(lensrt_render r, const char *path)
{
    file_header hd;
    char *tmp = NULL;
    FILE *f;
    size_t n;
    int ok, err = 0;
    lensrt_result res;
    if (!r || !path) return LENSRT_ERROR_INVALID_ARGUMENT;
    if ((res = lensrt_tiles_idle(r, "save")) != LENSRT_SUCCESS) return res;
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
    // Write a temporary file next to the target, then rename it over the target
    f = lensrt_fopen_temporary(&r->ctx->allocator, path, &tmp, &err);
    if (!f) {
        return lensrt_fail(r->ctx, LENSRT_ERROR_IO, "%s: cannot write phasor sums: %s", path, strerror(err));
    }
    ok = fwrite(&hd, sizeof hd, 1, f) == 1 && fwrite(r->sum, sizeof(double), 2 * n, f) == 2 * n &&
         (!r->sumsq || fwrite(r->sumsq, sizeof(double), n, f) == n);
    ok = (fclose(f) == 0) && ok;
    if (!ok || rename(tmp, path) != 0) {
        err = errno;
        remove(tmp);
        lensrt_free(r->ctx, tmp);
        return lensrt_fail(r->ctx, LENSRT_ERROR_IO, "%s: writing phasor sums failed: %s", path, strerror(err));
    }
    lensrt_free(r->ctx, tmp);
    return LENSRT_SUCCESS;
}

/* Read a phasor file that matches r's scene; sums go to new buffers. */
static lensrt_result read_file(lensrt_render r, const char *path, file_header *hd, double **sum, double **sumsq)
{
    FILE *f;
    size_t n = n_sums(r);
    uint64_t scene = scene_hash(r);
    int ok;
    *sum = *sumsq = NULL;
    f = fopen(path, "rb");
    if (!f) return lensrt_fail(r->ctx, LENSRT_ERROR_IO, "%s: cannot open phasor sums: %s", path, strerror(errno));
    if (fread(hd, sizeof *hd, 1, f) != 1 || memcmp(hd->magic, MAGIC, sizeof MAGIC) != 0 ||
        hd->marker != MARKER || hd->version != VERSION) {
        fclose(f);
        return lensrt_fail(r->ctx, LENSRT_ERROR_PARSE, "%s: not a lensrt-phasors %u file of this byte order", path, VERSION);
    }
    if (hd->width != r->width || hd->height != r->height || hd->n_wl != r->n_wl || hd->n_lights != r->n_lights ||
        hd->scene != scene || hd->has_sumsq != (r->sumsq != NULL)) {
        fclose(f);
        return lensrt_fail(r->ctx, LENSRT_ERROR_INCOMPATIBLE,
                           "%s: phasor sums of another scene (%d x %d pixels, %d wavelengths, %d lights%s); "
                           "the render has %d x %d, %d, %d and must match in lens, lights, aperture, focus, "
                           "window and estimator", path, hd->width, hd->height, hd->n_wl, hd->n_lights,
                           hd->scene != scene ? ", other settings" : "", r->width, r->height, r->n_wl, r->n_lights);
    }
    *sum = lensrt_alloc(r->ctx, sizeof(double) * 2 * n);
    if (hd->has_sumsq) *sumsq = lensrt_alloc(r->ctx, sizeof(double) * n);
    if (!*sum || (hd->has_sumsq && !*sumsq)) {
        fclose(f);
        lensrt_free(r->ctx, *sum);
        lensrt_free(r->ctx, *sumsq);
        return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "%s: out of memory", path);
    }
    ok = fread(*sum, sizeof(double), 2 * n, f) == 2 * n && (!hd->has_sumsq || fread(*sumsq, sizeof(double), n, f) == n);
    ok = ok && fgetc(f) == EOF;
    fclose(f);
    if (!ok) {
        lensrt_free(r->ctx, *sum);
        lensrt_free(r->ctx, *sumsq);
        return lensrt_fail(r->ctx, LENSRT_ERROR_PARSE, "%s: truncated or oversized phasor sums", path);
    }
    return LENSRT_SUCCESS;
}

lensrt_result lensrt_render_load(lensrt_render r, const char *path)
{
    file_header hd;
    double *sum, *sumsq;
    lensrt_result res;
    if (!r || !path) return LENSRT_ERROR_INVALID_ARGUMENT;
    if ((res = lensrt_tiles_idle(r, "load")) != LENSRT_SUCCESS) return res;
    if ((res = read_file(r, path, &hd, &sum, &sumsq)) != LENSRT_SUCCESS) return res;
    // Replace the sums; a later run() continues the saved sequence when the seed matches
    lensrt_free(r->ctx, r->sum);
    lensrt_free(r->ctx, r->sumsq);
    r->sum = sum;
    r->sumsq = sumsq;
    r->samples = hd.samples;
    r->splats = hd.splats;
    r->seconds = hd.seconds;
    if (hd.seed != r->desc.seed)
        lensrt_log(r->ctx, LENSRT_LOG_WARNING, "%s: saved with seed %llu, continuing with seed %llu", path,
                   (unsigned long long)hd.seed, (unsigned long long)r->desc.seed);
    return LENSRT_SUCCESS;
}

lensrt_result lensrt_render_merge(lensrt_render r, const char *path)
{
    file_header hd;
    double *sum, *sumsq;
    lensrt_result res;
    size_t i, n;
    if (!r || !path) return LENSRT_ERROR_INVALID_ARGUMENT;
    if ((res = lensrt_tiles_idle(r, "merge")) != LENSRT_SUCCESS) return res;
    if ((res = read_file(r, path, &hd, &sum, &sumsq)) != LENSRT_SUCCESS) return res;
    // The same seed means the same sample points: adding them would count them twice
    if (hd.seed == r->desc.seed && hd.samples > 0 && r->samples > 0) {
        lensrt_free(r->ctx, sum);
        lensrt_free(r->ctx, sumsq);
        return lensrt_fail(r->ctx, LENSRT_ERROR_INCOMPATIBLE,
                           "%s: rendered with the same seed %llu, so its samples repeat this render's; "
                           "merge renders made with different seeds (or use load to resume)",
                           path, (unsigned long long)hd.seed);
    }
    n = n_sums(r);
    for (i = 0; i < 2 * n; i++) r->sum[i] += sum[i];
    for (i = 0; sumsq && i < n; i++) r->sumsq[i] += sumsq[i];
    r->samples += hd.samples;
    r->splats += hd.splats;
    r->seconds += hd.seconds;
    lensrt_free(r->ctx, sum);
    lensrt_free(r->ctx, sumsq);
    return LENSRT_SUCCESS;
}
