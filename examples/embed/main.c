/* lensrt-embed: what a production renderer does with lensrt.
 *
 *   1. links a fitted lens in at build time (CMake: lensrt_add_lens) and loads nothing
 *      from files at run time;
 *   2. evaluates a batch of camera rays through the lens's polynomials on its own thread,
 *      with Jacobians (the direction of each ray arriving at the sensor is the gradient
 *      of its optical path over the sensor point);
 *   3. renders a point spread function in tiles on its own thread pool (here pthreads,
 *      in a renderer TBB or its own scheduler), and checks the tiles sum to exactly what
 *      one lensrt_render_run gives;
 *   4. renders the same PSF on the GL device in its own EGL context (made current by the
 *      renderer; lensrt only borrows it), when the machine has one, and checks that
 *      lensrt left its context current and its display initialised.
 *
 * Exit status 0 when every check holds. Usage: lensrt-embed [--require-gl]
 * (without a GL 4.3 device the GL part is skipped, unless --require-gl or
 * LENSRT_REQUIRE_GL=1 in the environment, as in CI). */
#include "lensrt.h"
#include "lensrt_lens_0001.h" /* made by lensrt_add_lens: the compiled-in lens 0001 */

#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#ifdef EMBED_WITH_EGL
#include <EGL/egl.h>
#include <EGL/eglext.h>
#endif

static void log_line(lensrt_log_level level, const char *message, void *user_data)
{
    (void)user_data;
    fprintf(stderr, "lensrt [%s] %s\n", level == LENSRT_LOG_ERROR ? "error" : level == LENSRT_LOG_WARNING ? "warning" : "info",
            message);
}

static int fail(lensrt_context ctx, const char *what, lensrt_result res)
{
    fprintf(stderr, "lensrt-embed: %s: %s: %s\n", what, lensrt_result_string(res),
            ctx ? lensrt_context_last_error(ctx) : "");
    return 1;
}

/* ------------------------------------------------------------ camera rays ----- */

/* A batch of rays from sensor points through stop points at 550 nm, through P_s in
 * float (a renderer's layout), with Jacobians; the same in double as the reference. */
static int camera_rays(lensrt_context ctx, lensrt_lens lens)
{
    enum { N = 256, IN = 6, OUT = 4 };
    static float in_f[N * IN], out_f[N * OUT], jac_f[N * OUT * IN];
    static double in_d[N * IN], out_d[N * OUT], jac_d[N * OUT * IN];
    lensrt_system_info si = LENSRT_SYSTEM_INFO_INIT;
    lensrt_eval_desc e = LENSRT_EVAL_DESC_INIT;
    lensrt_result res;
    double worst_dir = 0.0, worst_pos = 0.0, stop;
    int k;
    if ((res = lensrt_lens_system_info(lens, LENSRT_SYSTEM_SENSOR, &si)) != LENSRT_SUCCESS)
        return fail(ctx, "system info", res);
    // Sensor points over a quarter of the fitted image circle, stop points over half
    // the fitted stop, the sensor at the fitted focus range's lower end
    stop = 0.5 * si.input_max[3];
    for (k = 0; k < N; k++) {
        double t = (k + 0.5) / N, ang = 2.399963229728653 * k; /* golden angle */
        in_d[k * IN + 0] = 0.25 * si.input_max[0] * cos(7.0 * ang) * t;
        in_d[k * IN + 1] = 0.25 * si.input_max[1] * sin(7.0 * ang) * t;
        in_d[k * IN + 2] = si.input_min[2] > 0 ? si.input_min[2] : 0.0;
        in_d[k * IN + 3] = stop * sqrt(t) * cos(ang);
        in_d[k * IN + 4] = stop * sqrt(t) * sin(ang);
        in_d[k * IN + 5] = 550.0;
    }
    for (k = 0; k < N * IN; k++) in_f[k] = (float)in_d[k];
    e.system = LENSRT_SYSTEM_SENSOR;
    e.n_rays = N;
    e.type = LENSRT_TYPE_DOUBLE;
    e.inputs = in_d;
    e.outputs = out_d;
    e.jacobians = jac_d;
    if ((res = lensrt_lens_eval(ctx, lens, &e)) != LENSRT_SUCCESS) return fail(ctx, "eval (double)", res);
    e.type = LENSRT_TYPE_FLOAT;
    e.inputs = in_f;
    e.outputs = out_f;
    e.jacobians = jac_f;
    if ((res = lensrt_lens_eval(ctx, lens, &e)) != LENSRT_SUCCESS) return fail(ctx, "eval (float)", res);
    for (k = 0; k < N; k++) {
        // The ray's direction cosines where it meets the sensor: d phi_i / d (x_S, y_S)
        double dx = jac_d[(k * OUT + 3) * IN + 0], dy = jac_d[(k * OUT + 3) * IN + 1];
        double fx = jac_f[(k * OUT + 3) * IN + 0], fy = jac_f[(k * OUT + 3) * IN + 1];
        if (!(dx * dx + dy * dy < 1.0)) {
            fprintf(stderr, "lensrt-embed: ray %d: direction cosines (%g, %g) are not a direction\n", k, dx, dy);
            return 1;
        }
        worst_dir = fmax(worst_dir, fmax(fabs(fx - dx), fabs(fy - dy)));
        worst_pos = fmax(worst_pos, fmax(fabs(out_f[k * OUT] - out_d[k * OUT]), fabs(out_f[k * OUT + 1] - out_d[k * OUT + 1])));
    }
    printf("camera rays: %d rays through P_s (%d + %d terms for x_i, y_i): float against double: inner pupil "
           "%.2g mm, direction %.2g\n", N, si.n_terms[0], si.n_terms[1], worst_pos, worst_dir);
    // float carries 24 bits: positions of ~10 mm to ~1e-5 mm, directions to ~1e-6, a
    // sum of thousands of terms loses a few more bits
    if (worst_pos > 1e-3 || worst_dir > 1e-3) {
        fprintf(stderr, "lensrt-embed: float evaluation is further from double than float rounding explains\n");
        return 1;
    }
    return 0;
}

/* ------------------------------------------------------- tiles on a pool ----- */

#define TILE 16
#define THREADS 2

typedef struct pool {
    lensrt_render render;
    int width, height, next, n_tiles, tiles_x;
    lensrt_result first_error;
    pthread_mutex_t lock;
} pool;

/* A worker takes the next tile until none is left (what a renderer's scheduler does). */
static void *worker(void *arg)
{
    pool *p = arg;
    for (;;) {
        int t, x0, y0;
        lensrt_result res;
        pthread_mutex_lock(&p->lock);
        t = p->next < p->n_tiles ? p->next++ : -1;
        pthread_mutex_unlock(&p->lock);
        if (t < 0) return NULL;
        x0 = (t % p->tiles_x) * TILE;
        y0 = (t / p->tiles_x) * TILE;
        res = lensrt_render_tile(p->render, x0, y0, x0 + TILE <= p->width ? TILE : p->width - x0,
                                 y0 + TILE <= p->height ? TILE : p->height - y0);
        if (res != LENSRT_SUCCESS) {
            pthread_mutex_lock(&p->lock);
            if (p->first_error == LENSRT_SUCCESS) p->first_error = res;
            pthread_mutex_unlock(&p->lock);
        }
    }
}

static void scene(lensrt_render_desc *d, lensrt_lens lens, const lensrt_light *light, const double centre[2],
                  const double *wavelengths, int n_wl)
{
    static const lensrt_render_desc init = LENSRT_RENDER_DESC_INIT;
    *d = init;
    d->lens = lens;
    d->sensor.width = 48;
    d->sensor.height = 40;
    d->sensor.width_mm = 0.06;
    d->sensor.center_x_mm = centre[0];
    d->sensor.center_y_mm = centre[1];
    d->aperture.shape = LENSRT_APERTURE_BLADES;
    d->aperture.blades = 7;
    d->aperture.blade_curvature = 0.3;
    d->aperture.f_number = 8.0;
    d->lights = light;
    d->n_lights = 1;
    d->wavelengths_nm = wavelengths;
    d->n_wavelengths = n_wl;
    d->seed = 2024;
}

/* The PSF through lensrt_render_run and through tiles on our threads: the same bits. */
static int tiles_on_a_pool(lensrt_context ctx, const lensrt_render_desc *d, float *image, size_t count)
{
    lensrt_render whole = NULL, tiled = NULL;
    float *other = malloc(count * sizeof *other);
    pthread_t threads[THREADS];
    pool p;
    lensrt_result res;
    int i, status = 1;
    const uint64_t samples = 4096;
    memset(&p, 0, sizeof p);
    if (!other) return 1;
    if ((res = lensrt_render_create(ctx, d, &whole)) != LENSRT_SUCCESS ||
        (res = lensrt_render_create(ctx, d, &tiled)) != LENSRT_SUCCESS) {
        fail(ctx, "render", res);
        goto done;
    }
    if ((res = lensrt_render_run(whole, samples, NULL, NULL)) != LENSRT_SUCCESS) {
        fail(ctx, "run", res);
        goto done;
    }
    // Our pool: every tile of the window once, in whatever order the threads take them
    p.render = tiled;
    p.width = d->sensor.width;
    p.height = d->sensor.height;
    p.tiles_x = (p.width + TILE - 1) / TILE;
    p.n_tiles = p.tiles_x * ((p.height + TILE - 1) / TILE);
    pthread_mutex_init(&p.lock, NULL);
    if ((res = lensrt_render_tiles_begin(tiled, samples)) != LENSRT_SUCCESS) {
        fail(ctx, "tiles_begin", res);
        pthread_mutex_destroy(&p.lock);
        goto done;
    }
    for (i = 0; i < THREADS; i++) pthread_create(&threads[i], NULL, worker, &p);
    for (i = 0; i < THREADS; i++) pthread_join(threads[i], NULL);
    pthread_mutex_destroy(&p.lock);
    res = lensrt_render_tiles_end(tiled);
    if (p.first_error != LENSRT_SUCCESS || res != LENSRT_SUCCESS) {
        fail(ctx, "tiles", p.first_error != LENSRT_SUCCESS ? p.first_error : res);
        goto done;
    }
    if ((res = lensrt_render_image(whole, image, count)) != LENSRT_SUCCESS ||
        (res = lensrt_render_image(tiled, other, count)) != LENSRT_SUCCESS) {
        fail(ctx, "image", res);
        goto done;
    }
    if (memcmp(image, other, count * sizeof *image) != 0) {
        fprintf(stderr, "lensrt-embed: the tiles do not sum to what lensrt_render_run gives\n");
        goto done;
    }
    printf("tiles: %d tiles of %d x %d pixels on %d threads of ours: bit for bit the image of one "
           "lensrt_render_run\n", p.n_tiles, TILE, TILE, THREADS);
    status = 0;
done:
    lensrt_render_destroy(whole);
    lensrt_render_destroy(tiled);
    free(other);
    return status;
}

/* ------------------------------------------------ the renderer's GL context ----- */

#ifdef EMBED_WITH_EGL
/* Our own headless OpenGL 4.3 core context (Mesa's surfaceless platform or the default
 * display), current on this thread: what a renderer with a viewport already has. */
static int make_gl_context(EGLDisplay *dpy_out, EGLContext *ctx_out)
{
    static const EGLint attribs[] = {EGL_CONTEXT_MAJOR_VERSION, 4, EGL_CONTEXT_MINOR_VERSION, 3,
                                     EGL_CONTEXT_OPENGL_PROFILE_MASK, EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT, EGL_NONE};
    PFNEGLGETPLATFORMDISPLAYEXTPROC get_display =
        (PFNEGLGETPLATFORMDISPLAYEXTPROC)eglGetProcAddress("eglGetPlatformDisplayEXT");
    EGLDisplay dpy = EGL_NO_DISPLAY;
    EGLContext ctx;
    if (get_display) dpy = get_display(EGL_PLATFORM_SURFACELESS_MESA, EGL_DEFAULT_DISPLAY, NULL);
    if (dpy == EGL_NO_DISPLAY) dpy = eglGetDisplay(EGL_DEFAULT_DISPLAY);
    if (dpy == EGL_NO_DISPLAY || !eglInitialize(dpy, NULL, NULL)) return 0;
    if (!eglBindAPI(EGL_OPENGL_API)) return 0;
    ctx = eglCreateContext(dpy, EGL_NO_CONFIG_KHR, EGL_NO_CONTEXT, attribs);
    if (ctx == EGL_NO_CONTEXT) return 0;
    if (!eglMakeCurrent(dpy, EGL_NO_SURFACE, EGL_NO_SURFACE, ctx)) {
        eglDestroyContext(dpy, ctx);
        return 0;
    }
    *dpy_out = dpy;
    *ctx_out = ctx;
    return 1;
}

/* The PSF on the GL device in our context, against the CPU image. */
static int gl_in_our_context(const lensrt_render_desc *cpu_desc, const float *cpu, size_t count, int require)
{
    EGLDisplay dpy;
    EGLContext ours;
    lensrt_context_init init = LENSRT_CONTEXT_INIT;
    lensrt_context ctx = NULL;
    lensrt_lens lens = NULL;
    lensrt_render render = NULL;
    lensrt_render_desc d = *cpu_desc;
    lensrt_gl_info gi = LENSRT_GL_INFO_INIT;
    float *img = NULL;
    double num = 0.0, den = 0.0;
    lensrt_result res;
    size_t i;
    int status = 1;
    if (!make_gl_context(&dpy, &ours)) {
        printf("GL: no OpenGL 4.3 EGL context on this machine%s\n", require ? "" : ": skipped");
        return require ? 1 : 0;
    }
    // lensrt borrows the context current on this thread; it makes none of its own
    init.gl_platform = LENSRT_GL_PLATFORM_CALLER;
    init.log_fn = log_line;
    if ((res = lensrt_context_create(&init, &ctx)) != LENSRT_SUCCESS) {
        fail(NULL, "context", res);
        goto done;
    }
    if ((res = lensrt_context_gl_info(ctx, &gi)) != LENSRT_SUCCESS) {
        fail(ctx, "GL device", res);
        goto done;
    }
    if ((res = lensrt_lens_load_compiled(ctx, &lensrt_lens_0001, &lens)) != LENSRT_SUCCESS) {
        fail(ctx, "lens", res);
        goto done;
    }
    d.lens = lens;
    d.device = LENSRT_DEVICE_GL;
    img = malloc(count * sizeof *img);
    if (!img) goto done;
    if ((res = lensrt_render_create(ctx, &d, &render)) != LENSRT_SUCCESS ||
        (res = lensrt_render_run(render, 4096, NULL, NULL)) != LENSRT_SUCCESS ||
        (res = lensrt_render_image(render, img, count)) != LENSRT_SUCCESS) {
        fail(ctx, "GL render", res);
        goto done;
    }
    for (i = 0; i < count; i++) {
        num += ((double)img[i] - cpu[i]) * ((double)img[i] - cpu[i]);
        den += (double)cpu[i] * cpu[i];
    }
    printf("GL: %s in our context (platform %s): relative L2 distance to the CPU image %.2g\n", gi.renderer,
           gi.platform, sqrt(num / den));
    // The GL path splats in float with a basis at least as strict as the CPU's pruning
    // (tests/runtime/test_gl.py measures 4e-4 on this lens); 2e-3 leaves room for the
    // window and sample count here
    if (!(sqrt(num / den) < 2e-3)) {
        fprintf(stderr, "lensrt-embed: the GL image is further from the CPU image than float splats explain\n");
        goto done;
    }
    status = 0;
done:
    lensrt_render_destroy(render);
    lensrt_lens_destroy(ctx, lens);
    lensrt_context_destroy(ctx);
    free(img);
    // Our context is still ours: current, and its display initialised
    if (eglGetCurrentContext() != ours || eglQueryString(dpy, EGL_VERSION) == NULL) {
        fprintf(stderr, "lensrt-embed: lensrt left our EGL context or display changed\n");
        status = 1;
    }
    eglMakeCurrent(dpy, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
    eglDestroyContext(dpy, ours);
    // The display stays initialised until exit: Mesa 22's llvmpipe leaks 128 bytes when its
    // last display is terminated (with or without lensrt), which LeakSanitizer would report
    return status;
}
#endif

int main(int argc, char **argv)
{
    lensrt_context_init init = LENSRT_CONTEXT_INIT;
    lensrt_context ctx = NULL;
    lensrt_lens lens = NULL;
    lensrt_lens_info info = LENSRT_LENS_INFO_INIT;
    lensrt_light light = LENSRT_LIGHT_INIT;
    lensrt_render_desc desc;
    double centre[2], wavelengths[3] = {480.0, 550.0, 630.0};
    float *image = NULL;
    size_t count;
    const char *env = getenv("LENSRT_REQUIRE_GL");
    int require_gl = (argc > 1 && strcmp(argv[1], "--require-gl") == 0) || (env && strcmp(env, "1") == 0);
    int status = 1;
    lensrt_result res;

    // A library of another major version has other structs
    if (lensrt_version() / 1000000u != LENSRT_VERSION_MAJOR) {
        fprintf(stderr, "lensrt-embed: built for lensrt %d.x, running with %s\n", LENSRT_VERSION_MAJOR,
                lensrt_version_string());
        return 1;
    }
    init.log_fn = log_line;
    if ((res = lensrt_context_create(&init, &ctx)) != LENSRT_SUCCESS) return fail(NULL, "context", res);
    // The lens is part of this program: nothing is read from files
    if ((res = lensrt_lens_load_compiled(ctx, &lensrt_lens_0001, &lens)) != LENSRT_SUCCESS) {
        fail(ctx, "compiled-in lens", res);
        goto done;
    }
    lensrt_lens_get_info(lens, &info);
    printf("lensrt %s, compiled-in lens %s: fitted from f/%.2g, PSF within %.2g%% of exactly traced rays\n",
           lensrt_version_string(), info.name, info.f_number_min, 100.0 * info.psf_vs_exact);
    if (camera_rays(ctx, lens)) goto done;
    // A light 2 degrees off the axis, the window on its chief ray
    light.field_x_deg = -2.0; /* field angles of the chief ray (lensrt.h, lensrt_light) */
    light.field_y_deg = -1.0;
    if ((res = lensrt_lens_image_point(ctx, lens, &light, 550.0, 0.0, centre)) != LENSRT_SUCCESS) {
        fail(ctx, "image point", res);
        goto done;
    }
    scene(&desc, lens, &light, centre, wavelengths, 3);
    count = (size_t)3 * (size_t)desc.sensor.width * (size_t)desc.sensor.height;
    image = malloc(count * sizeof *image);
    if (!image || tiles_on_a_pool(ctx, &desc, image, count)) goto done;
#ifdef EMBED_WITH_EGL
    if (gl_in_our_context(&desc, image, count, require_gl)) goto done;
#else
    // A build without the GL path (LENSRT_WITH_GL=OFF) has no GL part to require
    (void)require_gl;
    printf("GL: this build has no GL path: skipped\n");
#endif
    status = 0;
done:
    free(image);
    lensrt_lens_destroy(ctx, lens);
    lensrt_context_destroy(ctx);
    return status;
}
