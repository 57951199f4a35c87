/* bench_gl.c: lensrt-bench's GL measurement (`--device gl` or `both`, the default): the
 * same scene with device LENSRT_DEVICE_GL, once per f-number after the lensrt
 * repetitions, bracketed by the baseline like them. The first run() of a GL render finds
 * the basis terms every pixel needs and compiles the splat shaders for them (one per
 * wavelength at most); that is set-up, not splatting, so each GL render first runs an
 * untimed warm-up of `--gl-warmup` samples per wavelength (default 256: it pays every
 * compile and the term search whatever its size) and the figure is the second run() call,
 * from the difference of the render's stats. A software GL (llvmpipe) is an order of
 * magnitude slower than the CPU path, so GL renders one pixel per 36 x 36 block (40 x 30
 * pixels over the same window; `--gl-stride`; its splats per second do not depend on the
 * pitch either) and `--gl-samples` per wavelength (default 16384, one pass). Without a GL
 * device the GL part is skipped with the reason; the CPU part still runs. */
#include "bench.h"

#include <stdint.h>
#include <stdio.h>
#include <string.h>

/* One GL render: create, the warm-up run() (untimed), then the timed run(); splats and
 * seconds of the timed call are the difference of the render's stats around it. */
static lensrt_result run_gl(lensrt_context ctx, const lensrt_render_desc *desc, long long warmup, long long samples,
                            gl_result *gr)
{
    lensrt_render render = NULL;
    lensrt_render_stats s0;
    lensrt_result r;
    double t0 = now_seconds();
    memset(&s0, 0, sizeof s0);
    s0.struct_size = sizeof s0;
    if ((r = lensrt_render_create(ctx, desc, &render)) != LENSRT_SUCCESS) return r;
    if (warmup > 0 && (r = lensrt_render_run(render, (uint64_t)warmup, NULL, NULL)) == LENSRT_SUCCESS)
        bench_stats(render, &s0);
    gr->setup_seconds = now_seconds() - t0;
    if (r == LENSRT_SUCCESS) r = lensrt_render_run(render, (uint64_t)samples, NULL, NULL);
    if (r == LENSRT_SUCCESS) {
        bench_stats(render, &gr->stats);
        gr->splats = (double)(gr->stats.splats - s0.splats);
        gr->seconds = gr->stats.seconds - s0.seconds;
        gr->sps = gr->splats / gr->seconds;
    }
    lensrt_render_destroy(render);
    return r;
}

/* The context's last error on one line (the GL device lists every platform it tried). */
static void last_error_line(lensrt_context ctx, lensrt_result r, char *buf, size_t size)
{
    const char *e = lensrt_context_last_error(ctx);
    char *p;
    snprintf(buf, size, "%s: %s", lensrt_result_string(r), e[0] ? e : "no message");
    for (p = buf; *p; p++)
        if (*p == '\n' || *p == '\r') *p = ' ';
}

/* Without a device `both` measures the CPU only and says why; `gl` exits with status 3. */
int gl_probe(lensrt_context ctx, const bench_options *o, gl_bench *g)
{
    lensrt_result r;
    memset(&g->info, 0, sizeof g->info);
    g->info.struct_size = sizeof g->info;
    if (o->do_gl) {
        r = lensrt_context_gl_info(ctx, &g->info);
        if (r == LENSRT_SUCCESS) {
            g->ok = 1;
        } else if (r == LENSRT_ERROR_NO_DEVICE || r == LENSRT_ERROR_UNSUPPORTED) {
            last_error_line(ctx, r, g->why, sizeof g->why);
            if (!o->do_cpu) {
                fprintf(stderr, "lensrt-bench: --device gl: %s\n", g->why);
                return 3;
            }
        } else {
            return fail(ctx, "GL device", r);
        }
    }
    return 0;
}

/* The GL lines of the bench's header. */
void gl_print_setup(const bench_options *o, const gl_bench *g)
{
    if (g->ok) {
        printf("  gl: %s, GL_RENDERER %s, GL_VERSION %s%s\n", g->info.platform, g->info.renderer, g->info.version,
               g->info.software ? " (software)" : "");
        printf("  gl: one render per f-number, bracketed by the baseline, one pixel per %ldx%ld block of the frame\n"
               "      (%ldx%ld pixels over the same window), %lld samples per wavelength timed ", o->gl_stride,
               o->gl_stride, o->gw, o->gh, o->gl_samples);
        if (o->gl_warmup > 0)
            printf("after an untimed\n      warm-up run() of %lld (shader compiles, terms per pixel)\n", o->gl_warmup);
        else
            printf("in the first run()\n      (shader compiles and terms per pixel included)\n");
    } else if (o->do_gl) {
        printf("  gl: skipped: %s\n", g->why);
    }
}

int gl_f_number(lensrt_context ctx, const lensrt_render_desc *desc, const baseline_scene *sc, const bench_options *o,
                int center_pixel, const f_result *fr, gl_bench *g)
{
    lensrt_render_desc gdesc = *desc;
    baseline_result pre, post;
    gl_result *gr = &g->res[g->n];
    lensrt_result r;
    // The same scene on its own pixel grid, bracketed by the baseline like a repetition
    memset(gr, 0, sizeof *gr);
    gr->f_number = fr->f_number;
    gdesc.device = LENSRT_DEVICE_GL;
    gdesc.sensor.width = (int)o->gw;
    gdesc.sensor.height = (int)o->gh;
    gdesc.seed = (uint64_t)o->seed;
    pre = run_baseline(sc, o->threads, 256, 0.5 * o->base_seconds, (uint64_t)o->seed + 2 * (uint64_t)o->reps,
                       center_pixel);
    r = run_gl(ctx, &gdesc, o->gl_warmup, o->gl_samples, gr);
    post = run_baseline(sc, o->threads, 256, 0.5 * o->base_seconds, (uint64_t)o->seed + 2 * (uint64_t)o->reps + 1,
                        center_pixel);
    if (pre.seconds < 0 || post.seconds < 0) {
        fprintf(stderr, "lensrt-bench: out of memory in the baseline\n");
        return 1;
    }
    if (r != LENSRT_SUCCESS) {
        // A device that fails mid-way: the CPU figures still count, the exit status says so
        last_error_line(ctx, r, g->why, sizeof g->why);
        printf(" [gl failed: %s]", g->why);
        g->ok = 0;
        g->failed = 1;
    } else {
        gr->base = combine(&pre, &post);
        gr->ratio_base = gr->sps / gr->base.splats_per_second;
        gr->ratio_cpu = fr->reps > 0 ? gr->sps / fr->sps_med : -1.0;
        printf(" [gl %.3g/s in %.1f s (set-up %.1f s), baseline %.3g/s: %.2fx", gr->sps, gr->seconds,
               gr->setup_seconds, gr->base.splats_per_second, gr->ratio_base);
        if (gr->ratio_cpu >= 0) printf(", %.3gx lensrt cpu", gr->ratio_cpu);
        printf("]");
        g->n++;
    }
    fflush(stdout);
    return 0;
}

/* The GL table (or why GL failed). */
void gl_print(const bench_options *o, const gl_bench *g, const f_result *res)
{
    int i;
    if (g->n > 0) {
        const gl_result *gh_ = NULL;
        printf("\ngl splats per second, %s on %s (%s),\none render per f-number, %ldx%ld pixels, %lld samples per "
               "wavelength (warm-up %lld)\n", g->info.renderer, g->info.platform,
               g->info.software ? "software" : "hardware", o->gw, o->gh, o->gl_samples, o->gl_warmup);
        printf("%-6s %9s %9s %10s %9s %7s %11s %8s %10s\n", "f/N", "stop mm", "seconds", "gl/s", "set-up s", "terms",
               "base Nt/s", "ratio", "vs cpu");
        for (i = 0; i < g->n; i++) {
            const gl_result *gr = &g->res[i];
            char vs[32] = "-";
            if (gr->ratio_cpu >= 0) snprintf(vs, sizeof vs, "%.3g", gr->ratio_cpu);
            printf("%-6g %9.4f %9.2f %10.3g %9.2f %7.2f %11.3g %8.2f %10s\n", gr->f_number, gr->stats.stop_radius_mm,
                   gr->seconds, gr->sps, gr->setup_seconds, gr->stats.phase_terms, gr->base.splats_per_second,
                   gr->ratio_base, vs);
            if (gr->f_number == res[o->head].f_number) gh_ = gr;
        }
        if (gh_) {
            printf("headline gl f/%g: %.3g splats/s, %.2fx the baseline at %d threads", gh_->f_number, gh_->sps,
                   gh_->ratio_base, o->threads);
            if (gh_->ratio_cpu >= 0) printf(", %.3gx lensrt on the cpu", gh_->ratio_cpu);
            printf(" (%s)\n", g->info.renderer);
        }
        printf("(ratio: gl / the %d-thread baseline that bracketed it; vs cpu: gl / the median lensrt cpu figure\n"
               " of the same f-number; terms: phase terms the gl splat shader evaluates, the most any pixel needs)\n",
               o->threads);
    } else if (g->failed) {
        printf("\ngl: failed: %s\n", g->why);
    }
}

/* The JSON's "gl": the device and one result per f-number, or why there are none. */
void gl_json(FILE *f, const bench_options *o, const gl_bench *g)
{
    int i;
    if (!g->info.renderer) {
        // No device (or not asked for): why
        fprintf(f, "{\"skipped\": ");
        json_string(f, o->do_gl ? g->why : "--device cpu");
        fprintf(f, "}");
    } else {
        fprintf(f, "{\"renderer\": ");
        json_string(f, g->info.renderer);
        fprintf(f, ", \"version\": ");
        json_string(f, g->info.version);
        fprintf(f, ", \"platform\": ");
        json_string(f, g->info.platform);
        fprintf(f, ", \"software\": %s,\n    \"stride\": %ld, \"rendered_resolution\": [%ld, %ld], "
                   "\"samples\": %lld, \"warmup_samples\": %lld, \"timing\": \"%s\",\n",
                g->info.software ? "true" : "false", o->gl_stride, o->gw, o->gh, o->gl_samples, o->gl_warmup,
                o->gl_warmup > 0 ? "the second run() of the render, after an untimed warm-up run()"
                                 : "the first run() of the render, shader compiles and set-up included");
        if (g->failed) {
            fprintf(f, "    \"error\": ");
            json_string(f, g->why);
            fprintf(f, ",\n");
        }
        fprintf(f, "    \"results\": [");
        for (i = 0; i < g->n; i++) {
            const gl_result *gr = &g->res[i];
            fprintf(f, "%s\n      {\"f_number\": %.17g, \"splats_per_second\": %.17g, \"seconds\": %.17g, "
                       "\"splats\": %.17g, \"setup_seconds\": %.17g, \"baseline_splats_per_second\": %.17g, "
                       "\"ratio_vs_baseline\": %.17g, \"ratio_vs_cpu\": ",
                    i ? "," : "", gr->f_number, gr->sps, gr->seconds, gr->splats, gr->setup_seconds,
                    gr->base.splats_per_second, gr->ratio_base);
            json_num(f, gr->ratio_cpu, gr->ratio_cpu >= 0);
            fprintf(f, ", \"stop_radius_mm\": %.17g, \"phase_terms\": %.17g, \"clip_fraction\": %.17g, "
                       "\"tau_fraction\": %.17g, \"dark_fraction\": %.17g}",
                    gr->stats.stop_radius_mm, gr->stats.phase_terms, gr->stats.clip_fraction,
                    gr->stats.tau_fraction, gr->stats.dark_fraction);
        }
        fprintf(f, "%s]}", g->n ? "\n    " : "");
    }
}
