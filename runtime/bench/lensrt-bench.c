/* lensrt-bench: splats per second of lensrt against the paper's algorithm as a plain
 * scalar double loop, measured in the same run (the machines are shared and noisy, so
 * the ratio is the figure to quote; absolute numbers are context).
 *
 *   lensrt-bench --json build/bench/lensrt.json
 *
 * A splat is one aperture sample evaluated at one pixel for one wavelength.
 *
 * The scene follows the paper's Figure 7: the default lens (0001), a point light off
 * the axis at infinity (field (-6, -4) deg), a 1440 x 1080 frame over 0.3 x 0.225 mm centred
 * on the light's image point, sensor shift 0.2 mm, 16 wavelengths, f/2, f/8 and f/32.
 *
 * This file: the options, the scene, the lensrt side and the report (the tables on
 * stdout, the JSON). lensrt side: lensrt_render_run() with the default precision and
 * sampler, one pass of 16384 samples per wavelength; clipping at both pupils and the
 * transmittance are evaluated inside; splats per second from bench_stats(). By default it
 * renders one pixel per 12 x 12 block of the frame (120 x 90 pixels over the same
 * window): lensrt's per-pixel work (the window's phase basis, the pruned terms) depends
 * on the window and not on the pixel pitch; `--stride 1` renders every pixel (about
 * 144 times longer: minutes per f-number on 2 cores). Each repetition is bracketed by
 * the baseline; the same render is then scheduled as host tiles.
 *
 * The other sides, each in its own file:
 *   baseline.c     the paper's Algorithm (section 3.2) over the generated Horner code of
 *                  the same lens, on as many OpenMP threads as lensrt and on one
 *   bench_tiles.c  the same renders as host-scheduled tiles on pthreads (`--tile WxH`)
 *   bench_gl.c     the same scene on the GL device (`--device gl` or `both`)
 *   bench.h        what they share: options, results, timing, medians, JSON helpers */
#include "bench.h"

#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#ifdef LENSRT_BENCH_OPENMP
#include <omp.h>
#endif

#ifndef LENSRT_GENERATED_DIR
#define LENSRT_GENERATED_DIR "generated"
#endif
#define DEFAULT_TABLE LENSRT_GENERATED_DIR "/0001-angenieux-double-gauss/lens0001.table"

#define DEFAULT_STRIDE 12
#define DEFAULT_GL_STRIDE 36
#define DEFAULT_GL_WARMUP 256

/* ------------------------------------------------------------------ options ----- */

static int max_threads(void)
{
#ifdef LENSRT_BENCH_OPENMP
    return omp_get_max_threads();
#else
    return 1;
#endif
}

static void usage(FILE *f)
{
    fprintf(f,
        "usage: lensrt-bench [options]\n"
        "  --json FILE            write the results as JSON\n"
        "  --table FILE           lens table (default: %s);\n"
        "                         the baseline always uses the compiled-in lens0001 polynomials\n"
        "  --resolution WxH       pixels of the frame (default 1440x1080)\n"
        "  --size WxH             the frame's window on the sensor in mm (default 0.3x0.225)\n"
        "  --stride K             lensrt renders one pixel per K x K block of the frame, (W/K) x (H/K)\n"
        "                         pixels over the same window (default %d; 1: every pixel). Its\n"
        "                         per-pixel work depends on the window, not on the pixel pitch, so\n"
        "                         this measures the frame's splats per second in 1/K^2 of the time\n"
        "  --samples N            aperture samples per wavelength per render (default 16384, one pass:\n"
        "                         the per-pixel set-up is paid once per pass)\n"
        "  --repeats R            renders per f-number, each bracketed by the baseline; medians are\n"
        "                         reported (default 3)\n"
        "  --f-numbers A,B,..     (default 2,8,32; the first 8 in the list, else the first, is the headline)\n"
        "  --wavelengths N        (default 16)\n"
        "  --field X,Y            the light's field angles in degrees (default -6,-4), at infinity\n"
        "  --focus Z              sensor shift z_S in mm (default 0.2)\n"
        "  --baseline-grid BxC    baseline pixels, a grid spread over the frame (default 8x8)\n"
        "  --baseline-seconds T   seconds of baseline per repetition, half right before and half right\n"
        "                         after the render (default 1)\n"
        "  --seed S               (default 1)\n"
        "  --device cpu|gl|both   what to measure against the baseline (default both); without a GL\n"
        "                         device `both` skips GL and says why, `gl` exits with status 3\n"
        "  --gl-platform auto|egl-device|egl-surfaceless|glfw\n"
        "                         where the GL context comes from (default auto: in that order)\n"
        "  --gl-stride K          GL renders one pixel per K x K block of the frame (default %d: a\n"
        "                         software GL is an order of magnitude slower than the CPU path)\n"
        "  --gl-samples N         aperture samples per wavelength of the timed GL run (default 16384)\n"
        "  --gl-warmup N          samples per wavelength of the untimed first run() of each GL render,\n"
        "                         which compiles the shaders and finds the terms per pixel (default %d;\n"
        "                         0: time the first call, set-up included)\n"
        "  --tile WxH             host-scheduled tiles of W x H pixels on as many pthreads as\n"
        "                         lensrt's OpenMP threads, against run() (default 32x32; 0x0: skip)\n",
        DEFAULT_TABLE, DEFAULT_STRIDE, DEFAULT_GL_STRIDE, DEFAULT_GL_WARMUP);
}

static int parse_pair_d(const char *s, char sep, double *a, double *b)
{
    char *end;
    if (!s) return 0;
    errno = 0;
    *a = strtod(s, &end);
    if (end == s || *end != sep) return 0;
    s = end + 1;
    *b = strtod(s, &end);
    return end != s && *end == '\0' && errno == 0 && isfinite(*a) && isfinite(*b);
}

static int parse_pair_i(const char *s, char sep, long *a, long *b)
{
    char *end;
    if (!s) return 0;
    errno = 0;
    *a = strtol(s, &end, 10);
    if (end == s || *end != sep) return 0;
    s = end + 1;
    *b = strtol(s, &end, 10);
    return end != s && *end == '\0' && errno == 0;
}

static int parse_d(const char *s, double *v)
{
    char *end;
    if (!s) return 0;
    errno = 0;
    *v = strtod(s, &end);
    return end != s && *end == '\0' && errno == 0 && isfinite(*v);
}

static void cpu_model(char *buf, size_t size)
{
    FILE *f = fopen("/proc/cpuinfo", "r");
    char line[512];
    snprintf(buf, size, "unknown");
    if (!f) return;
    while (fgets(line, sizeof line, f)) {
        char *colon = strchr(line, ':');
        if (strncmp(line, "model name", 10) == 0 && colon) {
            char *v = colon + 1, *e;
            while (*v == ' ' || *v == '\t') v++;
            e = v + strlen(v);
            while (e > v && (e[-1] == '\n' || e[-1] == '\r' || e[-1] == ' ')) *--e = '\0';
            snprintf(buf, size, "%s", v);
            break;
        }
    }
    fclose(f);
}

/* The defaults: the paper's Figure 7 scene. */
static void default_options(bench_options *o)
{
    const bench_options d = {.table = DEFAULT_TABLE, .device_arg = "both", .width = 1440, .height = 1080,
                             .stride = DEFAULT_STRIDE, .gx = 8, .gy = 8, .n_wl = 16, .reps = 3, .size_x = 0.3,
                             .size_y = 0.225, .field_x = -6.0, .field_y = -4.0, .focus = 0.2, .base_seconds = 1.0,
                             .f_numbers = {2.0, 8.0, 32.0}, .n_f = 3, .head = -1, .samples = 16384, .seed = 1,
                             .do_cpu = 1, .do_gl = 1, .gl_stride = DEFAULT_GL_STRIDE, .tile_w = 32, .tile_h = 32,
                             .gl_samples = 16384, .gl_warmup = DEFAULT_GL_WARMUP,
                             .gl_platform = LENSRT_GL_PLATFORM_AUTO};
    *o = d;
    o->threads = max_threads();
}

/* The command line into *o, and what follows from it. Returns -1 to go on, else the exit
 * status (0 after --help, 2 for a bad option). */
static int parse_options(int argc, char **argv, bench_options *o)
{
    int i;
    for (i = 1; i < argc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        const char *expected = NULL;        /* what a word-valued option takes */
        int ok = 1;
        if (strcmp(a, "-h") == 0 || strcmp(a, "--help") == 0) {
            usage(stdout);
            return 0;
        }
        if (!v) ok = 0;
        else if (strcmp(a, "--json") == 0) o->json = v;
        else if (strcmp(a, "--table") == 0) o->table = v;
        else if (strcmp(a, "--resolution") == 0)
            ok = parse_pair_i(v, 'x', &o->width, &o->height) && o->width > 0 && o->height > 0 && o->width <= 65536 &&
                 o->height <= 65536;
        else if (strcmp(a, "--size") == 0)
            ok = parse_pair_d(v, 'x', &o->size_x, &o->size_y) && o->size_x > 0 && o->size_y > 0;
        else if (strcmp(a, "--field") == 0) ok = parse_pair_d(v, ',', &o->field_x, &o->field_y);
        else if (strcmp(a, "--focus") == 0) ok = parse_d(v, &o->focus);
        else if (strcmp(a, "--tile") == 0)
            ok = parse_pair_i(v, 'x', &o->tile_w, &o->tile_h) &&
                 ((o->tile_w > 0 && o->tile_h > 0) || (o->tile_w == 0 && o->tile_h == 0));
        else if (strcmp(a, "--baseline-grid") == 0)
            ok = parse_pair_i(v, 'x', &o->gx, &o->gy) && o->gx > 0 && o->gy > 0 && o->gx * o->gy <= 65536;
        else if (strcmp(a, "--baseline-seconds") == 0) ok = parse_d(v, &o->base_seconds) && o->base_seconds >= 0;
        else if (strcmp(a, "--device") == 0) {
            expected = "expected cpu, gl or both";
            o->device_arg = v;
            o->do_cpu = strcmp(v, "gl") != 0;
            o->do_gl = strcmp(v, "cpu") != 0;
            ok = !o->do_cpu || !o->do_gl || strcmp(v, "both") == 0;
        } else if (strcmp(a, "--gl-platform") == 0) {
            expected = "expected auto, egl-device, egl-surfaceless or glfw";
            if (strcmp(v, "auto") == 0) o->gl_platform = LENSRT_GL_PLATFORM_AUTO;
            else if (strcmp(v, "egl-device") == 0) o->gl_platform = LENSRT_GL_PLATFORM_EGL_DEVICE;
            else if (strcmp(v, "egl-surfaceless") == 0) o->gl_platform = LENSRT_GL_PLATFORM_EGL_SURFACELESS;
            else if (strcmp(v, "glfw") == 0) o->gl_platform = LENSRT_GL_PLATFORM_GLFW;
            else ok = 0;
        } else if (strcmp(a, "--samples") == 0 || strcmp(a, "--seed") == 0 || strcmp(a, "--wavelengths") == 0 ||
                   strcmp(a, "--stride") == 0 || strcmp(a, "--repeats") == 0 || strcmp(a, "--gl-stride") == 0 ||
                   strcmp(a, "--gl-samples") == 0 || strcmp(a, "--gl-warmup") == 0) {
            char *end;
            long long x;
            errno = 0;
            x = strtoll(v, &end, 10);
            ok = end != v && *end == '\0' && errno == 0 && x >= 0;
            if (!ok) {
            } else if (strcmp(a, "--samples") == 0) {
                ok = x > 0;
                o->samples = x;
            } else if (strcmp(a, "--seed") == 0) {
                o->seed = x;
            } else if (strcmp(a, "--wavelengths") == 0) {
                ok = x > 0 && x <= MAX_WL;
                o->n_wl = (long)x;
            } else if (strcmp(a, "--stride") == 0) {
                ok = x >= 1 && x <= 65536;
                o->stride = (long)x;
            } else if (strcmp(a, "--gl-stride") == 0) {
                ok = x >= 1 && x <= 65536;
                o->gl_stride = (long)x;
            } else if (strcmp(a, "--gl-samples") == 0) {
                ok = x > 0 && x <= (long long)1 << 40;
                o->gl_samples = x;
            } else if (strcmp(a, "--gl-warmup") == 0) {
                ok = x <= (long long)1 << 40;
                o->gl_warmup = x;
            } else {
                ok = x >= 1 && x <= MAX_REP;
                o->reps = (long)x;
            }
        } else if (strcmp(a, "--f-numbers") == 0) {
            const char *p = v;
            o->n_f = 0;
            while (ok && *p && o->n_f < MAX_F) {
                char *end;
                o->f_numbers[o->n_f] = strtod(p, &end);
                if (end == p || !(o->f_numbers[o->n_f] > 0) || (*end != ',' && *end != '\0')) ok = 0;
                o->n_f++;
                p = *end == ',' ? end + 1 : end;
            }
            if (*p || o->n_f == 0) ok = 0;
        } else {
            fprintf(stderr, "lensrt-bench: unknown option %s\n", a);
            usage(stderr);
            return 2;
        }
        if (!ok && expected) {
            fprintf(stderr, "lensrt-bench: %s: %s, got '%s'\n", a, expected, v);
            return 2;
        }
        if (!ok) {
            fprintf(stderr, "lensrt-bench: %s: bad or missing value '%s'\n", a, v ? v : "");
            return 2;
        }
        i++;
    }
    for (i = 0; i < o->n_f && o->head < 0; i++)
        if (o->f_numbers[i] == 8.0) o->head = i;
    if (o->head < 0) o->head = 0;
    if (o->width % o->stride != 0 || o->height % o->stride != 0) {
        fprintf(stderr, "lensrt-bench: --stride %ld must divide the resolution %ldx%ld\n", o->stride, o->width,
                o->height);
        return 2;
    }
    if (o->do_gl && (o->width % o->gl_stride != 0 || o->height % o->gl_stride != 0)) {
        fprintf(stderr, "lensrt-bench: --gl-stride %ld must divide the resolution %ldx%ld\n", o->gl_stride, o->width,
                o->height);
        return 2;
    }
    o->rw = o->width / o->stride;
    o->rh = o->height / o->stride;
    o->gw = o->width / o->gl_stride;
    o->gh = o->height / o->gl_stride;
    return -1;
}

/* ------------------------------------------------------------------- main ----- */

int main(int argc, char **argv)
{
    bench_options o;
    gl_bench g;                              /* the GL device and its measurements */
    int i, k, center_pixel, status;
    double housing_first, housing_last, stop_f1, center[2], wl[MAX_WL], *pix = NULL, t_start = now_seconds();
    char cpu[256], date[64];
    lensrt_context ctx = NULL;
    lensrt_context_init init;
    lensrt_lens lens = NULL;
    lensrt_lens_info info;
    lensrt_light light;
    lensrt_result r;
    f_result res[MAX_F];
    time_t t = time(NULL);
    struct tm tmv;

    default_options(&o);
    if ((status = parse_options(argc, argv, &o)) >= 0) return status;
    status = 1;
    memset(&g, 0, sizeof g);

    // Lens facts the baseline needs, from the table's lens lines
    if (!table_lens_value(o.table, "housing_first_mm", &housing_first) ||
        !table_lens_value(o.table, "housing_last_mm", &housing_last) ||
        !table_lens_value(o.table, "stop_radius_f1_mm", &stop_f1)) {
        fprintf(stderr, "lensrt-bench: %s: expected lines `lens housing_first_mm`, `lens housing_last_mm` and "
                        "`lens stop_radius_f1_mm` (table version 2)\n", o.table);
        return 1;
    }

    {
        const lensrt_context_init zero_init = LENSRT_CONTEXT_INIT;
        init = zero_init;
    }
    init.gl_platform = o.gl_platform;
    if ((r = lensrt_context_create(&init, &ctx)) != LENSRT_SUCCESS) return fail(NULL, "context", r);
    if ((r = lensrt_lens_load(ctx, o.table, &lens)) != LENSRT_SUCCESS) {
        status = fail(ctx, o.table, r);
        goto done;
    }
    info.struct_size = sizeof info;
    lensrt_lens_get_info(lens, &info);
    memset(&light, 0, sizeof light);
    light.struct_size = sizeof light;
    light.field_x_deg = o.field_x;
    light.field_y_deg = o.field_y;
    if ((r = lensrt_lens_image_point(ctx, lens, &light, 0.5 * (info.wavelength_min_nm + info.wavelength_max_nm),
                                     o.focus, center)) != LENSRT_SUCCESS) {
        status = fail(ctx, "image point", r);
        goto done;
    }
    for (i = 0; i < o.n_wl; i++)
        wl[i] = info.wavelength_min_nm + (info.wavelength_max_nm - info.wavelength_min_nm) * (i + 0.5) / (double)o.n_wl;
    // The GL device first: without one, `both` measures the CPU only and says why
    if ((status = gl_probe(ctx, &o, &g)) != 0) goto done;
    status = 1;
    cpu_model(cpu, sizeof cpu);
    gmtime_r(&t, &tmv);
    strftime(date, sizeof date, "%Y-%m-%dT%H:%M:%SZ", &tmv);

    printf("lensrt-bench: %s\n", info.name);
    printf("  table %s\n", o.table);
    printf("  light (%g, %g) deg at infinity, image point (%.6f, %.6f) mm, focus offset %g mm\n",
           o.field_x, o.field_y, center[0], center[1], o.focus);
    printf("  frame %ldx%ld pixels over %g x %g mm, %ld wavelengths", o.width, o.height, o.size_x, o.size_y, o.n_wl);
    if (o.do_cpu) printf(", %lld samples per wavelength", o.samples);
    printf("\n");
    if (o.do_cpu && o.stride > 1)
        printf("  lensrt renders one pixel per %ldx%ld block of the frame: %ldx%ld pixels over the same window\n",
               o.stride, o.stride, o.rw, o.rh);
    if (o.do_cpu)
        printf("  %ld repetitions per f-number, each bracketed by %g s of the %d-thread baseline\n", o.reps,
               o.base_seconds, o.threads);
    gl_print_setup(&o, &g);
    printf("  housings: first %g mm, last %g mm; threads %d; cpu %s\n", housing_first, housing_last, o.threads, cpu);
    fflush(stdout);

    // Baseline pixels: a gx x gy grid of the frame's pixel centres
    if (!(pix = baseline_grid(o.gx, o.gy, o.width, o.height, o.size_x, o.size_y, center, &center_pixel))) {
        fprintf(stderr, "lensrt-bench: out of memory\n");
        goto done;
    }

    for (i = 0; i < o.n_f; i++) {
        lensrt_render_desc desc;
        baseline_scene sc;
        baseline_result b1[2];
        f_result *fr = &res[i];
        memset(fr, 0, sizeof *fr);
        memset(&desc, 0, sizeof desc);
        desc.struct_size = sizeof desc;
        desc.lens = lens;
        // The splat rate against the scalar baseline, which splats at pixel centres: the
        // point filter (the box filter's sub-pixel points are more pixels, same kernel)
        desc.pixel_filter = LENSRT_PIXEL_FILTER_POINT;
        desc.sensor.width = (int)o.rw;
        desc.sensor.height = (int)o.rh;
        desc.sensor.width_mm = o.size_x;
        desc.sensor.height_mm = o.size_y;
        desc.sensor.center_x_mm = center[0];
        desc.sensor.center_y_mm = center[1];
        desc.sensor.focus_offset_mm = o.focus;
        desc.aperture.f_number = o.f_numbers[i];
        desc.lights = &light;
        desc.n_lights = 1;
        desc.wavelengths_nm = wl;
        desc.n_wavelengths = (int)o.n_wl;
        fr->f_number = o.f_numbers[i];
        fr->reps = o.do_cpu ? (int)o.reps : 0;
        {
            // P_o's inputs for the light, by lensrt's own conversion (checked above)
            double xy[2];
            lensrt_light_direction_cosines(ctx, &light, xy);
            sc.light_x = xy[0];
            sc.light_y = xy[1];
        }
        sc.focus_mm = o.focus;
        sc.stop_radius_mm = stop_f1 / o.f_numbers[i];
        sc.housing_first_mm = housing_first;
        sc.housing_last_mm = housing_last;
        sc.n_wl = (int)o.n_wl;
        sc.wavelengths_nm = wl;
        sc.n_pix = (int)(o.gx * o.gy);
        sc.pix_xy = pix;
        printf("f/%g:", o.f_numbers[i]);
        fflush(stdout);
        b1[0] = run_baseline(&sc, 1, 256, 0.5 * o.base_seconds, (uint64_t)o.seed + 100, center_pixel);
        // Each repetition: baseline, lensrt, baseline, so that the two halves of the
        // baseline bracket the render in time and see the same machine
        for (k = 0; k < fr->reps; k++) {
            lensrt_render render = NULL;
            baseline_result pre, post;
            pre = run_baseline(&sc, o.threads, 256, 0.5 * o.base_seconds, (uint64_t)o.seed + 2 * (uint64_t)k,
                               center_pixel);
            desc.seed = (uint64_t)o.seed + (uint64_t)k;
            if ((r = lensrt_render_create(ctx, &desc, &render)) != LENSRT_SUCCESS) {
                status = fail(ctx, "render", r);
                goto done;
            }
            r = lensrt_render_run(render, (uint64_t)o.samples, NULL, NULL);
            if (r != LENSRT_SUCCESS) {
                status = fail(ctx, "run", r);
                lensrt_render_destroy(render);
                goto done;
            }
            bench_stats(render, &fr->stats);
            post = run_baseline(&sc, o.threads, 256, 0.5 * o.base_seconds, (uint64_t)o.seed + 2 * (uint64_t)k + 1,
                                center_pixel);
            if (pre.seconds < 0 || post.seconds < 0) {
                fprintf(stderr, "lensrt-bench: out of memory in the baseline\n");
                lensrt_render_destroy(render);
                goto done;
            }
            fr->baseN[k] = combine(&pre, &post);
            fr->sps[k] = fr->stats.splats_per_second;
            fr->seconds[k] = fr->stats.seconds;
            fr->ratio[k] = fr->sps[k] / fr->baseN[k].splats_per_second;
            printf(" [lensrt %.3g/s in %.1f s, baseline %.3g/s: %.0fx", fr->sps[k], fr->seconds[k],
                   fr->baseN[k].splats_per_second, fr->ratio[k]);
            // The same render (same seed) scheduled as tiles on pthreads
            if (o.tile_w > 0 && tiles_repetition(ctx, &desc, render, &o, fr, k) != LENSRT_SUCCESS) {
                lensrt_render_destroy(render);
                goto done;
            }
            printf("]");
            lensrt_render_destroy(render);
            fflush(stdout);
        }
        tiles_f_number(ctx, &desc, &o, fr);
        if (fr->reps > 0) {
            double bn[MAX_REP];
            for (k = 0; k < fr->reps; k++) bn[k] = fr->baseN[k].splats_per_second;
            fr->sps_med = median(fr->sps, fr->reps);
            fr->baseN_med = median(bn, fr->reps);
            fr->ratio_med = median(fr->ratio, fr->reps);
        }
        // GL: the same scene on its own pixel grid, bracketed by the baseline like a repetition
        if (g.ok && gl_f_number(ctx, &desc, &sc, &o, center_pixel, fr, &g) != 0) goto done;
        b1[1] = run_baseline(&sc, 1, 256, 0.5 * o.base_seconds, (uint64_t)o.seed + 101, center_pixel);
        if (b1[0].seconds < 0 || b1[1].seconds < 0) {
            fprintf(stderr, "lensrt-bench: out of memory in the baseline\n");
            goto done;
        }
        fr->base1 = combine(&b1[0], &b1[1]);
        printf(" 1 thread %.3g/s; baseline splats clipped: %.3g%%\n", fr->base1.splats_per_second,
               100.0 * fr->base1.clipped / fr->base1.splats);
        fflush(stdout);
    }

    // The tables
    if (o.do_cpu) {
        printf("\nsplats per second (one aperture sample at one pixel, one wavelength), median of %ld; %d threads\n",
               o.reps, o.threads);
        printf("%-6s %9s %9s %10s %7s %6s %6s %11s %11s %10s %8s %9s\n", "f/N", "stop mm", "seconds", "lensrt/s",
               "terms", "clip", "tau", "base Nt/s", "base 1t/s", "base coh.", "ratio", "ratio 1t");
        for (i = 0; i < o.n_f; i++) {
            const f_result *fr = &res[i];
            const lensrt_render_stats *st = &fr->stats;
            printf("%-6g %9.4f %9.2f %10.3g %7.2f %6.3f %6.3f %11.3g %11.3g %10.3f %8.1f %9.1f\n", fr->f_number,
                   st->stop_radius_mm, median(fr->seconds, fr->reps), fr->sps_med, st->phase_terms,
                   st->clip_fraction, st->tau_fraction, fr->baseN_med, fr->base1.splats_per_second,
                   fr->base1.coherence_center, fr->ratio_med, fr->sps_med / fr->base1.splats_per_second);
        }
        printf("headline f/%g: %.3g splats/s, %.1fx the scalar double baseline at %d threads (baseline %.3g splats/s)\n",
               res[o.head].f_number, res[o.head].sps_med, res[o.head].ratio_med, o.threads, res[o.head].baseN_med);
        printf("(ratio: median over the repetitions of lensrt / the %d-thread baseline that bracketed it; terms: phase\n"
               " terms per splat after pruning; clip, tau: fractions of pixels that needed the inner-pupil clip or a\n"
               " varying transmittance; base coh.: |sum X| / sum |X| of the baseline at the window centre, a check\n"
               " that its phases agree to a fraction of a wave across the aperture)\n", o.threads);
    }
    if (o.do_cpu && o.tile_w > 0) tiles_print(&o, res);
    gl_print(&o, &g, res);
    printf("(%.0f s in all)\n", now_seconds() - t_start);

    if (o.json) {
        FILE *f = fopen(o.json, "w");
        const f_result *h = &res[o.head];
        if (!f) {
            fprintf(stderr, "lensrt-bench: %s: %s\n", o.json, strerror(errno));
            goto done;
        }
        fprintf(f, "{\n  \"benchmark\": \"lensrt-bench\",\n  \"lens\": ");
        json_string(f, info.name);
        fprintf(f, ",\n  \"table\": ");
        json_string(f, o.table);
        fprintf(f, ",\n  \"date\": \"%s\",\n  \"cpu\": ", date);
        json_string(f, cpu);
        fprintf(f, ",\n  \"threads\": %d,\n", o.threads);
        fprintf(f, "  \"resolution\": [%ld, %ld],\n  \"stride\": %ld,\n  \"rendered_resolution\": [%ld, %ld],\n",
                o.width, o.height, o.stride, o.rw, o.rh);
        fprintf(f, "  \"window_mm\": [%.17g, %.17g],\n", o.size_x, o.size_y);
        fprintf(f, "  \"center_mm\": [%.17g, %.17g],\n  \"focus_offset_mm\": %.17g,\n", center[0], center[1], o.focus);
        fprintf(f, "  \"light_field_deg\": [%.17g, %.17g],\n  \"wavelengths\": %ld,\n  \"samples\": %lld,\n",
                o.field_x, o.field_y, o.n_wl, o.samples);
        fprintf(f, "  \"repeats\": %d,\n  \"f_number\": %.17g,\n", h->reps, h->f_number);
        fprintf(f, "  \"device\": ");
        json_string(f, o.device_arg);
        fprintf(f, ",\n  \"splats_per_second\": ");
        json_num(f, h->sps_med, o.do_cpu);
        fprintf(f, ",\n  \"baseline_splats_per_second\": ");
        json_num(f, h->baseN_med, o.do_cpu);
        fprintf(f, ",\n  \"baseline_threads\": %d,\n", o.threads);
        fprintf(f, "  \"baseline_single_thread_splats_per_second\": %.17g,\n", h->base1.splats_per_second);
        fprintf(f, "  \"ratio\": ");
        json_num(f, h->ratio_med, o.do_cpu);
        fprintf(f, ",\n  \"ratio_vs_single_thread\": ");
        json_num(f, h->sps_med / h->base1.splats_per_second, o.do_cpu);
        fprintf(f, ",\n");
        fprintf(f, "  \"baseline\": {\"algorithm\": \"paper section 3.2 as a plain scalar double loop: generated Horner "
                   "lens0001_P_o_d once per sample, lens0001_P_s_d per splat, housing clips, amplitude "
                   "sqrt(tau_o tau_i), phase 2 pi / lambda (phi_o + phi_i), libm cos/sin\", \"pixels\": %ld, "
                   "\"grid\": [%ld, %ld], \"seconds_per_repetition\": %.17g, \"housing_first_mm\": %.17g, "
                   "\"housing_last_mm\": %.17g},\n",
                o.gx * o.gy, o.gx, o.gy, o.base_seconds, housing_first, housing_last);
        fprintf(f, "  \"per_f_number\": {");
        for (i = 0; i < o.n_f && o.do_cpu; i++) {
            const f_result *fr = &res[i];
            const lensrt_render_stats *st = &fr->stats;
            double bn[MAX_REP];
            for (k = 0; k < fr->reps; k++) bn[k] = fr->baseN[k].splats_per_second;
            fprintf(f, "%s\n    \"%g\": {\"splats_per_second\": %.17g, \"baseline_splats_per_second\": %.17g, "
                       "\"ratio\": %.17g, \"baseline_single_thread_splats_per_second\": %.17g, "
                       "\"stop_radius_mm\": %.17g, \"splats\": %llu, \"samples_per_wavelength\": %llu, "
                       "\"phase_terms\": %.17g, \"clip_fraction\": %.17g, \"tau_fraction\": %.17g, "
                       "\"dark_fraction\": %.17g, \"baseline_coherence_center\": %.17g, "
                       "\"baseline_clipped_fraction\": %.17g,\n      \"repetitions\": ",
                    i ? "," : "", fr->f_number, fr->sps_med, fr->baseN_med, fr->ratio_med,
                    fr->base1.splats_per_second, st->stop_radius_mm, (unsigned long long)st->splats,
                    (unsigned long long)st->samples_per_wavelength, st->phase_terms, st->clip_fraction,
                    st->tau_fraction, st->dark_fraction, fr->base1.coherence_center,
                    fr->base1.clipped / fr->base1.splats);
            fprintf(f, "{\"splats_per_second\": ");
            json_list(f, fr->sps, fr->reps);
            fprintf(f, ", \"seconds\": ");
            json_list(f, fr->seconds, fr->reps);
            fprintf(f, ", \"baseline_splats_per_second\": ");
            json_list(f, bn, fr->reps);
            fprintf(f, ", \"ratio\": ");
            json_list(f, fr->ratio, fr->reps);
            fprintf(f, "}}");
        }
        fprintf(f, "\n  },\n  \"gl\": ");
        gl_json(f, &o, &g);
        // Host-scheduled tiles: the headline, then per f-number
        fprintf(f, ",\n  \"tiles\": ");
        tiles_json(f, &o, res);
        fprintf(f, ",\n  \"wall_seconds\": %.17g\n}\n", now_seconds() - t_start);
        if (fclose(f) != 0) {
            fprintf(stderr, "lensrt-bench: %s: write failed\n", o.json);
            goto done;
        }
        printf("wrote %s\n", o.json);
    }
    status = g.failed ? 1 : 0;
done:
    free(pix);
    if (lens) lensrt_lens_destroy(ctx, lens);
    lensrt_context_destroy(ctx);
    return status;
}