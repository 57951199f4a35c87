/*
 * test_gl_caller: lensrt inside a host that uses EGL itself.
 *
 * The test plays the host: it makes its own OpenGL 4.3 core context on Mesa's
 * surfaceless EGL display (llvmpipe without a GPU), makes it current and sets some GL
 * state of its own. Then:
 *   1. LENSRT_GL_PLATFORM_CALLER: lensrt renders on the host's context. The GL image
 *      agrees with the CPU's (the tolerance of tests/runtime/test_gl.py, see below);
 *      after every call the host's context is current and its GL state (program, shader
 *      storage bindings) is as it set it; a call made without the host's context current
 *      fails with LENSRT_ERROR_DEVICE and a message; after lensrt_context_destroy the
 *      host's display is initialised, its context current and usable.
 *   2. CALLER without a current context, or with an OpenGL ES one: LENSRT_ERROR_NO_DEVICE
 *      with a message saying why.
 *   3. lensrt's own context on the same surfaceless display, which the host initialised:
 *      lensrt gives the host back its current context and bound API after each call,
 *      and destroying the lensrt context leaves the host's display initialised and its
 *      context usable (EGL displays are per-process singletons: an eglTerminate by lensrt
 *      would destroy the host's context).
 *   4. Two lensrt contexts on that display: destroying one leaves the other rendering.
 *
 *   test_gl_caller LENS_TABLE
 *
 * Without EGL's surfaceless platform or an OpenGL 4.3 context the test is skipped
 * (exit 77), or fails when LENSRT_REQUIRE_GL=1 (CI).
 */
#include "lensrt.h"

#include <EGL/egl.h>
#include <EGL/eglext.h>
#include <GL/glcorearb.h>

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define SKIP 77 /* ctest's SKIP_RETURN_CODE */

/* ------------------------------------------------------------- harness ----- */

#include "check.h"

/* No device here: skip, or fail when CI requires GL. */
static int no_device(const char *reason)
{
    const char *require = getenv("LENSRT_REQUIRE_GL");
    if (require && require[0] && strcmp(require, "0") != 0) {
        fprintf(stderr, "test_gl_caller: FAILED: LENSRT_REQUIRE_GL is set but there is no GL device: %s\n", reason);
        return 1;
    }
    printf("test_gl_caller: skipped: no OpenGL 4.3 device: %s\n", reason);
    return SKIP;
}

/* ------------------------------------------------------------------ host ----- */

/* The host's GL entry points (through eglGetProcAddress: no libGL is linked). */
typedef struct host_gl {
    PFNGLGETSTRINGPROC GetString;
    PFNGLGETERRORPROC GetError;
    PFNGLGETINTEGERVPROC GetIntegerv;
    PFNGLGETINTEGERI_VPROC GetIntegeri_v;
    PFNGLGETINTEGER64I_VPROC GetInteger64i_v;
    PFNGLGENBUFFERSPROC GenBuffers;
    PFNGLDELETEBUFFERSPROC DeleteBuffers;
    PFNGLBINDBUFFERPROC BindBuffer;
    PFNGLBINDBUFFERBASEPROC BindBufferBase;
    PFNGLBINDBUFFERRANGEPROC BindBufferRange;
    PFNGLBUFFERDATAPROC BufferData;
    PFNGLGETBUFFERSUBDATAPROC GetBufferSubData;
    PFNGLCREATESHADERPROC CreateShader;
    PFNGLSHADERSOURCEPROC ShaderSource;
    PFNGLCOMPILESHADERPROC CompileShader;
    PFNGLDELETESHADERPROC DeleteShader;
    PFNGLCREATEPROGRAMPROC CreateProgram;
    PFNGLATTACHSHADERPROC AttachShader;
    PFNGLLINKPROGRAMPROC LinkProgram;
    PFNGLGETPROGRAMIVPROC GetProgramiv;
    PFNGLDELETEPROGRAMPROC DeleteProgram;
    PFNGLUSEPROGRAMPROC UseProgram;
    PFNGLDISPATCHCOMPUTEPROC DispatchCompute;
    PFNGLMEMORYBARRIERPROC MemoryBarrier;
} host_gl;

typedef struct host {
    EGLDisplay display;
    EGLContext context;
    host_gl gl;
    GLuint program;          /* a compute program: writes i + 42 into binding 5 */
    GLuint buffers[3];       /* bound: [0] generic and range at 3, [1] base at 0, [2] scratch */
} host;

/* Bindings the host sets and checks (the render uses binding points 0 .. 17). */
#define CHECKED_BINDINGS 24
#define RANGE_INDEX 3
#define RANGE_SIZE 64

static const char *PROGRAM_TEXT = "#version 430 core\n"
                                  "layout(local_size_x = 1) in;\n"
                                  "layout(std430, binding = 5) buffer Out { uint v[]; };\n"
                                  "void main() { v[gl_GlobalInvocationID.x] = gl_GlobalInvocationID.x + 42u; }\n";

/* A function pointer from eglGetProcAddress into a typed field (same size and
 * representation on every platform EGL runs on; copied, not cast through a pointer). */
#define LOAD(field, name)                                                                     \
    do {                                                                                      \
        __eglMustCastToProperFunctionPointerType proc_ = eglGetProcAddress(name);             \
        memcpy(&h->gl.field, &proc_, sizeof h->gl.field);                                     \
    } while (0)

static int load_host_gl(host *h)
{
    LOAD(GetString, "glGetString");
    LOAD(GetError, "glGetError");
    LOAD(GetIntegerv, "glGetIntegerv");
    LOAD(GetIntegeri_v, "glGetIntegeri_v");
    LOAD(GetInteger64i_v, "glGetInteger64i_v");
    LOAD(GenBuffers, "glGenBuffers");
    LOAD(DeleteBuffers, "glDeleteBuffers");
    LOAD(BindBuffer, "glBindBuffer");
    LOAD(BindBufferBase, "glBindBufferBase");
    LOAD(BindBufferRange, "glBindBufferRange");
    LOAD(BufferData, "glBufferData");
    LOAD(GetBufferSubData, "glGetBufferSubData");
    LOAD(CreateShader, "glCreateShader");
    LOAD(ShaderSource, "glShaderSource");
    LOAD(CompileShader, "glCompileShader");
    LOAD(DeleteShader, "glDeleteShader");
    LOAD(CreateProgram, "glCreateProgram");
    LOAD(AttachShader, "glAttachShader");
    LOAD(LinkProgram, "glLinkProgram");
    LOAD(GetProgramiv, "glGetProgramiv");
    LOAD(DeleteProgram, "glDeleteProgram");
    LOAD(UseProgram, "glUseProgram");
    LOAD(DispatchCompute, "glDispatchCompute");
    LOAD(MemoryBarrier, "glMemoryBarrier");
    return h->gl.GetString && h->gl.GetError && h->gl.GetIntegerv && h->gl.GetIntegeri_v && h->gl.GetInteger64i_v &&
           h->gl.GenBuffers && h->gl.DeleteBuffers && h->gl.BindBuffer && h->gl.BindBufferBase &&
           h->gl.BindBufferRange && h->gl.BufferData && h->gl.GetBufferSubData && h->gl.CreateShader &&
           h->gl.ShaderSource && h->gl.CompileShader && h->gl.DeleteShader && h->gl.CreateProgram &&
           h->gl.AttachShader && h->gl.LinkProgram && h->gl.GetProgramiv && h->gl.DeleteProgram &&
           h->gl.UseProgram && h->gl.DispatchCompute && h->gl.MemoryBarrier;
}

/* The host's display (surfaceless), an OpenGL 4.3 core context made current, its
 * program and buffers bound; 0, or 1 and the reason when there is no such device. */
static int make_host(host *h, char *why, size_t size)
{
    static const EGLint attribs[] = {EGL_CONTEXT_MAJOR_VERSION, 4, EGL_CONTEXT_MINOR_VERSION, 3,
                                     EGL_CONTEXT_OPENGL_PROFILE_MASK, EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT, EGL_NONE};
    const char *client = eglQueryString(EGL_NO_DISPLAY, EGL_EXTENSIONS);
    PFNEGLGETPLATFORMDISPLAYEXTPROC get_display =
        (PFNEGLGETPLATFORMDISPLAYEXTPROC)eglGetProcAddress("eglGetPlatformDisplayEXT");
    GLuint shader;
    GLint ok = 0;
    memset(h, 0, sizeof *h);
    if (!client || !strstr(client, "EGL_MESA_platform_surfaceless") || !get_display) {
        snprintf(why, size, "EGL has no surfaceless platform (EGL_MESA_platform_surfaceless)");
        return 1;
    }
    h->display = get_display(EGL_PLATFORM_SURFACELESS_MESA, (void *)EGL_DEFAULT_DISPLAY, NULL);
    if (h->display == EGL_NO_DISPLAY || !eglInitialize(h->display, NULL, NULL)) {
        snprintf(why, size, "no surfaceless display (0x%x)", (unsigned)eglGetError());
        return 1;
    }
    if (!eglBindAPI(EGL_OPENGL_API) ||
        (h->context = eglCreateContext(h->display, (EGLConfig)0, EGL_NO_CONTEXT, attribs)) == EGL_NO_CONTEXT ||
        !eglMakeCurrent(h->display, EGL_NO_SURFACE, EGL_NO_SURFACE, h->context)) {
        snprintf(why, size, "no OpenGL 4.3 core context (0x%x)", (unsigned)eglGetError());
        return 1;
    }
    if (!load_host_gl(h)) {
        snprintf(why, size, "GL entry points missing");
        return 1;
    }
    // The host's own state: a program in use, a generic binding, a base and a range binding
    shader = h->gl.CreateShader(GL_COMPUTE_SHADER);
    h->gl.ShaderSource(shader, 1, &PROGRAM_TEXT, NULL);
    h->gl.CompileShader(shader);
    h->program = h->gl.CreateProgram();
    h->gl.AttachShader(h->program, shader);
    h->gl.LinkProgram(h->program);
    h->gl.DeleteShader(shader);
    h->gl.GetProgramiv(h->program, GL_LINK_STATUS, &ok);
    if (!ok) {
        snprintf(why, size, "the host's compute program does not link");
        return 1;
    }
    h->gl.GenBuffers(3, h->buffers);
    h->gl.BindBuffer(GL_SHADER_STORAGE_BUFFER, h->buffers[1]);
    h->gl.BufferData(GL_SHADER_STORAGE_BUFFER, 256, NULL, GL_DYNAMIC_COPY);
    h->gl.BindBuffer(GL_SHADER_STORAGE_BUFFER, h->buffers[0]);
    h->gl.BufferData(GL_SHADER_STORAGE_BUFFER, 4 * RANGE_SIZE, NULL, GL_DYNAMIC_COPY);
    h->gl.BindBufferBase(GL_SHADER_STORAGE_BUFFER, 0, h->buffers[1]);
    h->gl.BindBufferRange(GL_SHADER_STORAGE_BUFFER, RANGE_INDEX, h->buffers[0], 0, RANGE_SIZE);
    h->gl.BindBuffer(GL_SHADER_STORAGE_BUFFER, h->buffers[0]); /* BindBufferBase/Range set it too */
    h->gl.UseProgram(h->program);
    if (h->gl.GetError() != GL_NO_ERROR) {
        snprintf(why, size, "GL errors while setting up the host's state");
        return 1;
    }
    return 0;
}

/* The host's context is current and its GL state as make_host left it. */
static void check_host_state(const host *h, const char *after)
{
    GLint v = -1, i;
    CHECK(eglGetCurrentContext() == h->context && eglGetCurrentDisplay() == h->display,
          "after %s: the host's context is not current (%p)", after, (void *)eglGetCurrentContext());
    if (eglGetCurrentContext() != h->context) return;
    h->gl.GetIntegerv(GL_CURRENT_PROGRAM, &v);
    CHECK(v == (GLint)h->program, "after %s: current program %d, the host's is %u", after, (int)v, h->program);
    h->gl.GetIntegerv(GL_SHADER_STORAGE_BUFFER_BINDING, &v);
    CHECK(v == (GLint)h->buffers[0], "after %s: shader storage buffer %d, the host's is %u", after, (int)v,
          h->buffers[0]);
    for (i = 0; i < CHECKED_BINDINGS; i++) {
        GLint64 start = -1, length = -1;
        GLint want = i == 0 ? (GLint)h->buffers[1] : i == RANGE_INDEX ? (GLint)h->buffers[0] : 0;
        h->gl.GetIntegeri_v(GL_SHADER_STORAGE_BUFFER_BINDING, (GLuint)i, &v);
        h->gl.GetInteger64i_v(GL_SHADER_STORAGE_BUFFER_START, (GLuint)i, &start);
        h->gl.GetInteger64i_v(GL_SHADER_STORAGE_BUFFER_SIZE, (GLuint)i, &length);
        CHECK(v == want && start == 0 && length == (i == RANGE_INDEX ? RANGE_SIZE : 0),
              "after %s: shader storage binding %d holds buffer %d [%lld, +%lld), the host's %d [0, +%d)", after,
              (int)i, (int)v, (long long)start, (long long)length, (int)want, i == RANGE_INDEX ? RANGE_SIZE : 0);
    }
    CHECK(h->gl.GetError() == GL_NO_ERROR, "after %s: a GL error is pending", after);
}

/* The host's display is initialised, its context current and it computes: its program
 * writes i + 42 into a buffer, read back. */
static void check_host_usable(host *h, const char *after)
{
    GLuint out[4] = {0, 0, 0, 0};
    const char *version = eglQueryString(h->display, EGL_VERSION);
    EGLint error = eglGetError();
    CHECK(version != NULL, "after %s: the host's display is no longer initialised (eglQueryString(EGL_VERSION) "
          "failed: 0x%x)", after, (unsigned)error);
    CHECK(eglGetCurrentContext() == h->context, "after %s: the host's context is not current", after);
    CHECK(h->gl.GetString(GL_VERSION) != NULL, "after %s: glGetString(GL_VERSION) failed", after);
    h->gl.BindBuffer(GL_SHADER_STORAGE_BUFFER, h->buffers[2]);
    h->gl.BufferData(GL_SHADER_STORAGE_BUFFER, sizeof out, out, GL_DYNAMIC_COPY);
    h->gl.BindBufferBase(GL_SHADER_STORAGE_BUFFER, 5, h->buffers[2]);
    h->gl.UseProgram(h->program);
    h->gl.DispatchCompute(4, 1, 1);
    h->gl.MemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
    h->gl.BindBuffer(GL_SHADER_STORAGE_BUFFER, h->buffers[2]);
    h->gl.GetBufferSubData(GL_SHADER_STORAGE_BUFFER, 0, sizeof out, out);
    CHECK(out[0] == 42 && out[3] == 45, "after %s: the host's program wrote %u %u %u %u, expected 42 43 44 45", after,
          out[0], out[1], out[2], out[3]);
    CHECK(h->gl.GetError() == GL_NO_ERROR, "after %s: GL error while the host computes", after);
    // Back to the state check_host_state expects
    h->gl.BindBufferBase(GL_SHADER_STORAGE_BUFFER, 5, 0);
    h->gl.BindBuffer(GL_SHADER_STORAGE_BUFFER, h->buffers[0]);
}

/* ---------------------------------------------------------------- lensrt ----- */

static lensrt_context new_context(lensrt_gl_platform platform)
{
    lensrt_context_init init = LENSRT_CONTEXT_INIT;
    lensrt_context ctx = NULL;
    init.gl_platform = platform;
    init.threads = 2;
    if (lensrt_context_create(&init, &ctx) != LENSRT_SUCCESS) {
        fprintf(stderr, "test_gl_caller: lensrt_context_create failed\n");
        exit(1);
    }
    return ctx;
}

#define SIZE 24
#define N_WL 2
#define N_PIX (N_WL * SIZE * SIZE)

/* test_gl.py's "f8-axis" scene: lens 0001 at f/8 on the axis, in focus, 24 x 24 pixels
 * over 0.03 mm, 450 and 650 nm, 16384 samples, seed 3. 0 on success. */
static lensrt_result render(lensrt_context ctx, lensrt_lens lens, int device, int precision, float *img,
                            lensrt_render *keep)
{
    static const double WAVELENGTHS[N_WL] = {450.0, 650.0};
    lensrt_light light = LENSRT_LIGHT_INIT;
    lensrt_render_desc d = LENSRT_RENDER_DESC_INIT;
    lensrt_render r = NULL;
    double centre[2] = {0, 0};
    lensrt_result res = lensrt_lens_image_point(ctx, lens, &light, 580.0, 0.0, centre);
    d.lens = lens;
    d.sensor.width = d.sensor.height = SIZE;
    d.sensor.width_mm = 0.03;
    d.sensor.center_x_mm = centre[0];
    d.sensor.center_y_mm = centre[1];
    d.aperture.f_number = 8.0;
    d.lights = &light;
    d.n_lights = 1;
    d.wavelengths_nm = WAVELENGTHS;
    d.n_wavelengths = N_WL;
    d.seed = 3;
    d.device = device;
    d.precision = precision;
    if (res == LENSRT_SUCCESS) res = lensrt_render_create(ctx, &d, &r);
    if (res == LENSRT_SUCCESS) res = lensrt_render_run(r, 1 << 14, NULL, NULL);
    if (res == LENSRT_SUCCESS) res = lensrt_render_image(r, img, N_PIX);
    if (keep && res == LENSRT_SUCCESS) *keep = r;
    else lensrt_render_destroy(r);
    return res;
}

static double rel_l2(const float *a, const float *b, size_t n)
{
    double num = 0, den = 0;
    size_t i;
    for (i = 0; i < n; i++) {
        num += ((double)a[i] - b[i]) * ((double)a[i] - b[i]);
        den += (double)b[i] * b[i];
    }
    return den > 0 ? sqrt(num / den) : INFINITY;
}

/* 1. The host's own context. */
static void test_caller(host *h, const char *table)
{
    /* Float rounding floor of the GL path against a double reference (test_gl.py): a
     * splat's float phase sum of up to a few hundred waves (eps 6e-8: 2e-5 waves, 1e-4
     * rad); a coherent worst case turns a phase error e into 2e of intensity: 2e-4 */
    const double FLOAT_FLOOR = 2e-4;
    static float ref[N_PIX], cpu[N_PIX], img[N_PIX], again[N_PIX];
    lensrt_context ctx = new_context(LENSRT_GL_PLATFORM_CALLER);
    lensrt_gl_info info = LENSRT_GL_INFO_INIT;
    lensrt_lens lens = NULL;
    lensrt_render kept = NULL;
    lensrt_result res;
    double err_cpu, err_gl;
    CHECK_OK(ctx, lensrt_context_gl_info(ctx, &info));
    check_host_state(h, "lensrt_context_gl_info");
    CHECK(info.platform && strcmp(info.platform, "caller") == 0, "platform '%s', expected 'caller'",
          info.platform ? info.platform : "(null)");
    CHECK(info.renderer && strcmp(info.renderer, (const char *)h->gl.GetString(GL_RENDERER)) == 0,
          "renderer '%s', the host's is '%s'", info.renderer ? info.renderer : "(null)",
          (const char *)h->gl.GetString(GL_RENDERER));
    CHECK_OK(ctx, lensrt_lens_load(ctx, table, &lens));
    if (!lens) {
        lensrt_context_destroy(ctx);
        return;
    }
    // Same seed and samples on both devices, the CPU in double the reference: the GL
    // image may be no further from it than 3x the CPU default's distance (its basis
    // truncation bound is at least as strict, on other terms) plus the float floor
    CHECK_OK(ctx, render(ctx, lens, LENSRT_DEVICE_CPU, LENSRT_PRECISION_DOUBLE, ref, NULL));
    CHECK_OK(ctx, render(ctx, lens, LENSRT_DEVICE_CPU, LENSRT_PRECISION_DEFAULT, cpu, NULL));
    CHECK_OK(ctx, render(ctx, lens, LENSRT_DEVICE_GL, LENSRT_PRECISION_DEFAULT, img, &kept));
    check_host_state(h, "a GL render on the caller's context");
    err_cpu = rel_l2(cpu, ref, N_PIX);
    err_gl = rel_l2(img, ref, N_PIX);
    printf("test_gl_caller: caller's context (%s): CPU default vs double %.2e, GL vs double %.2e\n", info.renderer,
           err_cpu, err_gl);
    CHECK(err_gl <= 3 * err_cpu + FLOAT_FLOOR, "GL on the caller's context vs CPU double: %.3e > 3 x %.3e + %.0e",
          err_gl, err_cpu, FLOAT_FLOOR);
    // Without the host's context current, a call on the GL render fails and says why
    if (kept) {
        eglMakeCurrent(h->display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
        res = lensrt_render_run(kept, 256, NULL, NULL);
        CHECK(res == LENSRT_ERROR_DEVICE, "run without the caller's context current: %s", lensrt_result_string(res));
        CHECK(strstr(lensrt_context_last_error(ctx), "not current") != NULL, "message: '%s'",
              lensrt_context_last_error(ctx));
        CHECK(eglGetCurrentContext() == EGL_NO_CONTEXT, "lensrt made a context current");
        eglMakeCurrent(h->display, EGL_NO_SURFACE, EGL_NO_SURFACE, h->context);
        // With it current again the render goes on: the 256 samples were not drawn
        CHECK_OK(ctx, lensrt_render_image(kept, again, N_PIX));
        CHECK(memcmp(again, img, sizeof img) == 0, "the failed run changed the sums");
        lensrt_render_destroy(kept);
        check_host_state(h, "lensrt_render_destroy");
    }
    lensrt_lens_destroy(ctx, lens);
    lensrt_context_destroy(ctx);
    check_host_state(h, "lensrt_context_destroy");
    check_host_usable(h, "lensrt_context_destroy (caller)");
}

/* 2. CALLER without a usable context. */
static void test_caller_refused(host *h)
{
    static const EGLint es_attribs[] = {EGL_CONTEXT_MAJOR_VERSION, 3, EGL_CONTEXT_MINOR_VERSION, 1, EGL_NONE};
    lensrt_gl_info info = LENSRT_GL_INFO_INIT;
    lensrt_context ctx = new_context(LENSRT_GL_PLATFORM_CALLER);
    lensrt_result res;
    EGLContext es;
    // No context current at all
    eglMakeCurrent(h->display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
    res = lensrt_context_gl_info(ctx, &info);
    CHECK(res == LENSRT_ERROR_NO_DEVICE && strstr(lensrt_context_last_error(ctx), "no EGL context is current"),
          "CALLER without a current context: %s (%s)", lensrt_result_string(res), lensrt_context_last_error(ctx));
    lensrt_context_destroy(ctx);
    // An OpenGL ES 3.1 context (it has compute shaders, but not the desktop GLSL 4.30)
    eglBindAPI(EGL_OPENGL_ES_API);
    es = eglCreateContext(h->display, (EGLConfig)0, EGL_NO_CONTEXT, es_attribs);
    if (es != EGL_NO_CONTEXT && eglMakeCurrent(h->display, EGL_NO_SURFACE, EGL_NO_SURFACE, es)) {
        ctx = new_context(LENSRT_GL_PLATFORM_CALLER);
        res = lensrt_context_gl_info(ctx, &info);
        CHECK(res == LENSRT_ERROR_NO_DEVICE && strstr(lensrt_context_last_error(ctx), "not desktop OpenGL"),
              "CALLER with an OpenGL ES context: %s (%s)", lensrt_result_string(res), lensrt_context_last_error(ctx));
        CHECK(eglGetCurrentContext() == es, "lensrt changed the current context");
        lensrt_context_destroy(ctx);
        eglMakeCurrent(h->display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
        eglDestroyContext(h->display, es);
    } else {
        printf("test_gl_caller: no OpenGL ES 3.1 context here (0x%x): that check is left out\n",
               (unsigned)eglGetError());
    }
    eglBindAPI(EGL_OPENGL_API);
    eglMakeCurrent(h->display, EGL_NO_SURFACE, EGL_NO_SURFACE, h->context);
    check_host_state(h, "the refused CALLER contexts");
}

/* 3 and 4. lensrt's own contexts on the host's display. */
static void test_own_display(host *h, const char *table)
{
    static float first[N_PIX], second[N_PIX];
    lensrt_context a = new_context(LENSRT_GL_PLATFORM_EGL_SURFACELESS);
    lensrt_context b = new_context(LENSRT_GL_PLATFORM_EGL_SURFACELESS);
    lensrt_gl_info info = LENSRT_GL_INFO_INIT;
    lensrt_lens lens_a = NULL, lens_b = NULL;
    // The thread's bound API is per-thread state: lensrt binds OpenGL to make its context
    // and must give the host's back
    eglBindAPI(EGL_OPENGL_ES_API);
    CHECK_OK(a, lensrt_context_gl_info(a, &info));
    CHECK(eglQueryAPI() == EGL_OPENGL_ES_API, "lensrt left the thread's bound API at 0x%x, the host's is ES",
          (unsigned)eglQueryAPI());
    eglBindAPI(EGL_OPENGL_API);
    CHECK(info.platform && strcmp(info.platform, "egl-surfaceless") == 0, "platform '%s'",
          info.platform ? info.platform : "(null)");
    check_host_state(h, "lensrt making its own context");
    CHECK_OK(a, lensrt_lens_load(a, table, &lens_a));
    CHECK_OK(b, lensrt_lens_load(b, table, &lens_b));
    if (lens_a && lens_b) {
        CHECK_OK(a, render(a, lens_a, LENSRT_DEVICE_GL, LENSRT_PRECISION_DEFAULT, first, NULL));
        check_host_state(h, "a GL render on lensrt's own context");
        CHECK_OK(b, render(b, lens_b, LENSRT_DEVICE_GL, LENSRT_PRECISION_DEFAULT, first, NULL));
        // Context a goes; b, on the same display, renders on
        lensrt_lens_destroy(a, lens_a);
        lensrt_context_destroy(a);
        a = NULL;
        check_host_usable(h, "destroying a lensrt context with its own display");
        check_host_state(h, "destroying a lensrt context with its own display");
        CHECK_OK(b, render(b, lens_b, LENSRT_DEVICE_GL, LENSRT_PRECISION_DEFAULT, second, NULL));
        CHECK(memcmp(first, second, sizeof first) == 0, "after another lensrt context went, the image changed");
    }
    lensrt_lens_destroy(b, lens_b);
    lensrt_context_destroy(b);
    if (a) {
        lensrt_lens_destroy(a, lens_a);
        lensrt_context_destroy(a);
    }
    check_host_usable(h, "destroying every lensrt context");
    check_host_state(h, "destroying every lensrt context");
}

int main(int argc, char **argv)
{
    host h;
    char why[256];
    if (argc != 2) {
        fprintf(stderr, "usage: test_gl_caller LENS_TABLE\n");
        return 2;
    }
    if (make_host(&h, why, sizeof why)) return no_device(why);
    check_host_state(&h, "setting up the host");
    test_caller(&h, argv[1]);
    test_caller_refused(&h);
    test_own_display(&h, argv[1]);
    // The host tears down what it made, but leaves the display initialised (as lensrt
    // does): eglTerminate of the last display unloads Mesa's driver, and a 128-byte block
    // the driver keeps (reachable while it is loaded) then shows as a leak in the
    // sanitizer build, in a host that never called lensrt as well
    h.gl.DeleteBuffers(3, h.buffers);
    h.gl.DeleteProgram(h.program);
    eglMakeCurrent(h.display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
    eglDestroyContext(h.display, h.context);
    printf("test_gl_caller: %d checks, %d failed\n", g_checks, g_failures);
    return g_failures ? 1 : 0;
}
