/* bench_tiles.c: lensrt-bench's host-scheduled tiles (`--tile WxH`, default 32x32; 0x0
 * skips them). Right after each repetition's bracketing baseline, the same render (same
 * seed) scheduled by the host as lensrt_render_tiles_begin, lensrt_render_tile on as many
 * pthreads as lensrt's OpenMP threads (tiles of W x H pixels, smaller at the right and
 * bottom edges, taken in row-major order from a shared counter), lensrt_render_tiles_end;
 * its splats per second (wall time from begin to end) against the run() of the same
 * repetition, and whether its image equals run()'s bit for bit. A session prepares each
 * (pass, wavelength)'s samples once and its tiles share them (core/tiles.c): the cost of
 * one 1 x 1 tile in a session of its own (it prepares every slot itself) is measured once
 * per f-number. */
#include "bench.h"

#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Host-scheduled tiles: a pool of pthreads taking W x H tiles from a shared counter. */
typedef struct tile_pool {
    lensrt_render render;
    int width, height, tw, th, nx, n, next;
    lensrt_result first_error;
    pthread_mutex_t lock;
} tile_pool;

static void *tile_worker(void *arg)
{
    tile_pool *p = arg;
    for (;;) {
        int k, x0, y0;
        lensrt_result r;
        pthread_mutex_lock(&p->lock);
        k = p->next < p->n ? p->next++ : -1;
        pthread_mutex_unlock(&p->lock);
        if (k < 0) return NULL;
        x0 = (k % p->nx) * p->tw;
        y0 = (k / p->nx) * p->th;
        r = lensrt_render_tile(p->render, x0, y0, x0 + p->tw <= p->width ? p->tw : p->width - x0,
                               y0 + p->th <= p->height ? p->th : p->height - y0);
        if (r != LENSRT_SUCCESS) {
            pthread_mutex_lock(&p->lock);
            if (p->first_error == LENSRT_SUCCESS) p->first_error = r;
            pthread_mutex_unlock(&p->lock);
        }
    }
}

/* One tile-scheduled render of `samples` per wavelength on `threads` pthreads; the
 * number of tiles in *n_tiles. */
static lensrt_result run_tiles(lensrt_render render, uint64_t samples, int width, int height, int tw, int th,
                               int threads, int *n_tiles)
{
    pthread_t th_[64];
    tile_pool p;
    lensrt_result r;
    int i, started = 0;
    if (threads > 64) threads = 64;
    memset(&p, 0, sizeof p);
    p.render = render;
    p.width = width;
    p.height = height;
    p.tw = tw;
    p.th = th;
    p.nx = (width + tw - 1) / tw;
    p.n = p.nx * ((height + th - 1) / th);
    *n_tiles = p.n;
    if ((r = lensrt_render_tiles_begin(render, samples)) != LENSRT_SUCCESS) return r;
    pthread_mutex_init(&p.lock, NULL);
    for (i = 0; i < threads; i++) started += pthread_create(&th_[started], NULL, tile_worker, &p) == 0;
    if (started == 0) tile_worker(&p); /* no thread could be made: the caller's alone */
    for (i = 0; i < started; i++) pthread_join(th_[i], NULL);
    pthread_mutex_destroy(&p.lock);
    r = lensrt_render_tiles_end(render);
    return p.first_error != LENSRT_SUCCESS ? p.first_error : r;
}

/* Seconds of one 1 x 1 tile alone in its session: drawing and preparing every pass's and
 * wavelength's samples (the session's shared preparation), plus one pixel's splats. The session is then refused (the other pixels
 * are not covered) and the render left as it was. */
static double one_tile_seconds(lensrt_context ctx, const lensrt_render_desc *desc, uint64_t samples)
{
    lensrt_render render = NULL;
    double t0, t1;
    if (lensrt_render_create(ctx, desc, &render) != LENSRT_SUCCESS) return -1.0;
    if (lensrt_render_tiles_begin(render, samples) != LENSRT_SUCCESS) {
        lensrt_render_destroy(render);
        return -1.0;
    }
    t0 = now_seconds();
    lensrt_render_tile(render, 0, 0, 1, 1);
    t1 = now_seconds();
    lensrt_render_tiles_end(render); /* refused: 1 pixel of many */
    lensrt_render_destroy(render);
    return t1 - t0;
}

/* Whether two renders' images are equal bit for bit (-1: could not compare). */
static int same_image(lensrt_render a, lensrt_render b, size_t count)
{
    float *ia = malloc(sizeof(float) * count), *ib = malloc(sizeof(float) * count);
    int same = -1;
    if (ia && ib && lensrt_render_image(a, ia, count) == LENSRT_SUCCESS && lensrt_render_image(b, ib, count) == LENSRT_SUCCESS)
        same = memcmp(ia, ib, sizeof(float) * count) == 0;
    free(ia);
    free(ib);
    return same;
}

lensrt_result tiles_repetition(lensrt_context ctx, const lensrt_render_desc *desc, lensrt_render run,
                               const bench_options *o, f_result *fr, int k)
{
    lensrt_render tiled = NULL;
    lensrt_render_stats ts;
    lensrt_result r;
    int n_tiles = 0, same;
    memset(&ts, 0, sizeof ts);
    if ((r = lensrt_render_create(ctx, desc, &tiled)) != LENSRT_SUCCESS ||
        (r = run_tiles(tiled, (uint64_t)o->samples, (int)o->rw, (int)o->rh, (int)o->tile_w, (int)o->tile_h,
                       o->threads, &n_tiles)) != LENSRT_SUCCESS) {
        fail(ctx, "tiles", r);
        lensrt_render_destroy(tiled);
        return r;
    }
    bench_stats(tiled, &ts);
    same = same_image(run, tiled, (size_t)o->rw * (size_t)o->rh * (size_t)o->n_wl);
    if (k == 0) fr->tile_identical = same;
    else if (same != 1) fr->tile_identical = same;
    fr->tile_sps[k] = ts.splats_per_second;
    fr->tile_seconds[k] = ts.seconds;
    fr->tile_ratio[k] = fr->tile_sps[k] / fr->sps[k];
    printf("; %d tiles %.3g/s in %.1f s: %.2fx run%s", n_tiles, fr->tile_sps[k], fr->tile_seconds[k],
           fr->tile_ratio[k], same == 1 ? ", same image" : same == 0 ? ", IMAGE DIFFERS" : "");
    lensrt_render_destroy(tiled);
    return LENSRT_SUCCESS;
}

void tiles_f_number(lensrt_context ctx, const lensrt_render_desc *desc, const bench_options *o, f_result *fr)
{
    lensrt_render_desc d = *desc;
    if (o->tile_w > 0 && fr->reps > 0) {
        d.seed = (uint64_t)o->seed;
        fr->one_tile_seconds = one_tile_seconds(ctx, &d, (uint64_t)o->samples);
        fr->tile_sps_med = median(fr->tile_sps, fr->reps);
        fr->tile_ratio_med = median(fr->tile_ratio, fr->reps);
    }
}

/* The table of tiles against run(), per f-number. */
void tiles_print(const bench_options *o, const f_result *res)
{
    int i;
    const int n_tiles = (int)(((o->rw + o->tile_w - 1) / o->tile_w) * ((o->rh + o->tile_h - 1) / o->tile_h));
    printf("\nhost-scheduled tiles of %ldx%ld pixels (%d tiles of the %ldx%ld window) on %d pthreads against\n"
           "run() on %d OpenMP threads, same renders, median of %ld\n", o->tile_w, o->tile_h, n_tiles, o->rw, o->rh,
           o->threads, o->threads, o->reps);
    printf("%-6s %10s %10s %8s %12s %11s %11s\n", "f/N", "run/s", "tiles/s", "ratio", "1x1 tile s", "prep share",
           "same image");
    for (i = 0; i < o->n_f; i++) {
        const f_result *fr = &res[i];
        // The session prepares the samples once, shared by its tiles
        double share = fr->one_tile_seconds / (median(fr->tile_seconds, fr->reps) * o->threads);
        printf("%-6g %10.3g %10.3g %8.3f %12.4f %10.1f%% %11s\n", fr->f_number, fr->sps_med, fr->tile_sps_med,
               fr->tile_ratio_med, fr->one_tile_seconds, 100.0 * share,
               fr->tile_identical == 1 ? "yes" : fr->tile_identical == 0 ? "NO" : "?");
    }
    printf("headline tiles f/%g: %.3g splats/s, %.3fx run() (%ldx%ld tiles, %d pthreads)\n", res[o->head].f_number,
           res[o->head].tile_sps_med, res[o->head].tile_ratio_med, o->tile_w, o->tile_h, o->threads);
    printf("(ratio: tiles / run() of the same repetition; 1x1 tile s: a session's sample preparation, drawing\n"
           " and preparing every wavelength's samples once for all its tiles (a lone 1x1 tile does it all);\n"
           " prep share: that cost over the tiled render's thread-seconds; same image: the tiled render's\n"
           " image equals run()'s bit for bit)\n");
}

/* The JSON's "tiles": the headline, then per f-number, or why there are none. */
void tiles_json(FILE *f, const bench_options *o, const f_result *res)
{
    const f_result *h = &res[o->head];
    int i;
    if (!o->do_cpu || o->tile_w == 0) {
        fprintf(f, "{\"skipped\": ");
        json_string(f, !o->do_cpu ? "--device gl" : "--tile 0x0");
        fprintf(f, "}");
    } else {
        fprintf(f, "{\"tile\": [%ld, %ld], \"tiles\": %ld, \"threads\": %d, \"scheduler\": \"pthreads, tiles in "
                   "row-major order from a shared counter\", \"f_number\": %.17g, \"splats_per_second\": %.17g, "
                   "\"ratio_vs_run\": %.17g,\n    \"per_f_number\": {",
                o->tile_w, o->tile_h, ((o->rw + o->tile_w - 1) / o->tile_w) * ((o->rh + o->tile_h - 1) / o->tile_h),
                o->threads, h->f_number, h->tile_sps_med, h->tile_ratio_med);
        for (i = 0; i < o->n_f; i++) {
            const f_result *fr = &res[i];
            fprintf(f, "%s\n      \"%g\": {\"splats_per_second\": %.17g, \"ratio_vs_run\": %.17g, "
                       "\"one_tile_seconds\": %.17g, \"identical_to_run\": %s, \"repetitions\": "
                       "{\"splats_per_second\": ",
                    i ? "," : "", fr->f_number, fr->tile_sps_med, fr->tile_ratio_med, fr->one_tile_seconds,
                    fr->tile_identical == 1 ? "true" : "false");
            json_list(f, fr->tile_sps, fr->reps);
            fprintf(f, ", \"seconds\": ");
            json_list(f, fr->tile_seconds, fr->reps);
            fprintf(f, ", \"ratio_vs_run\": ");
            json_list(f, fr->tile_ratio, fr->reps);
            fprintf(f, "}}");
        }
        fprintf(f, "\n    }}");
    }
}
