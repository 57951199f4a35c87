/* The GL device: a headless OpenGL 4.3 core context, found in this order (AUTO):
 *   1. the EGL device platform (EGL_EXT_platform_device), non-software devices first:
 *      NVIDIA's driver and Mesa's hardware drivers offer their GPUs here;
 *   2. Mesa's surfaceless platform (EGL_MESA_platform_surfaceless): llvmpipe on a
 *      machine without a GPU;
 *   3. GLFW 3.3 with a hidden window, under an X server (xvfb-run on a server).
 * Every library is opened at run time; the reason each platform failed goes into the
 * error message. */
#include "gl_device.h"

#include <dlfcn.h>
#include <stdio.h>
#include <string.h>

/* GLFW 3.3 constants (glfw3.h); GLFW is only opened at run time */
#define GLFW_VISIBLE 0x00020004
#define GLFW_CONTEXT_VERSION_MAJOR 0x00022002
#define GLFW_CONTEXT_VERSION_MINOR 0x00022003
#define GLFW_OPENGL_FORWARD_COMPAT 0x00022006
#define GLFW_OPENGL_PROFILE 0x00022008
#define GLFW_OPENGL_CORE_PROFILE 0x00032001

static const char *platform_name(lensrt_gl_platform p)
{
    return p == LENSRT_GL_PLATFORM_EGL_DEVICE ? "egl-device"
           : p == LENSRT_GL_PLATFORM_EGL_SURFACELESS ? "egl-surfaceless" : "glfw";
}

/* A symbol of a dlopen()ed library as a function pointer (POSIX guarantees the cast). */
static lensrt_gl_proc lib_proc(void *lib, const char *name)
{
    lensrt_gl_proc f;
    void *p = dlsym(lib, name);
    memcpy(&f, &p, sizeof f);
    return f;
}

/* A GL entry point through the platform's loader. */
static lensrt_gl_proc get_proc(const lensrt_gl *gl, const char *name)
{
    if (gl->glfw_get_proc_address) return gl->glfw_get_proc_address(name);
    return (lensrt_gl_proc)gl->egl_get_proc_address(name);
}

/* Fetch the GL entry points and check the version; 0 on success, else a reason in why. */
static int load_gl(lensrt_gl *gl, char *why, size_t size)
{
    GLint major = 0, minor = 0;
    const char *renderer;
#define LENSRT_GL_LOAD(type, name)                                                \
    if (!(gl->name = (type)get_proc(gl, "gl" #name))) {                                    \
        snprintf(why, size, "no entry point gl%s", #name);                        \
        return 1;                                                                 \
    }
    LENSRT_GL_FUNCTIONS(LENSRT_GL_LOAD)
#undef LENSRT_GL_LOAD
    gl->GetIntegerv(GL_MAJOR_VERSION, &major);
    gl->GetIntegerv(GL_MINOR_VERSION, &minor);
    renderer = (const char *)gl->GetString(GL_RENDERER);
    if (major * 10 + minor < 43) {
        snprintf(why, size, "OpenGL %d.%d on %s, compute shaders need 4.3", major, minor, renderer ? renderer : "?");
        return 1;
    }
    snprintf(gl->renderer, sizeof gl->renderer, "%s", renderer ? renderer : "unknown");
    snprintf(gl->version, sizeof gl->version, "%s", (const char *)gl->GetString(GL_VERSION));
    gl->software = strstr(gl->renderer, "llvmpipe") || strstr(gl->renderer, "softpipe") ||
                   strstr(gl->renderer, "swrast") || strstr(gl->renderer, "Software");
    major = 0;
    gl->GetIntegeri_v(GL_MAX_COMPUTE_WORK_GROUP_COUNT, 0, &major);
    gl->max_groups_x = major > 0 ? major : 65535;
    if (gl->GetError() != GL_NO_ERROR) {
        snprintf(why, size, "GL errors while querying %s", gl->renderer);
        return 1;
    }
    return 0;
}

/* ------------------------------------------------------------------- EGL ----- */

typedef struct egl_api {
    PFNEGLGETPROCADDRESSPROC get_proc_address;
    PFNEGLQUERYSTRINGPROC query_string;
    PFNEGLGETPLATFORMDISPLAYEXTPROC get_platform_display;
    PFNEGLQUERYDEVICESEXTPROC query_devices;
    PFNEGLQUERYDEVICESTRINGEXTPROC query_device_string;
    PFNEGLINITIALIZEPROC initialize;
    PFNEGLTERMINATEPROC terminate;
    PFNEGLBINDAPIPROC bind_api;
    PFNEGLCREATECONTEXTPROC create_context;
    PFNEGLDESTROYCONTEXTPROC destroy_context;
    PFNEGLMAKECURRENTPROC make_current;
    PFNEGLGETERRORPROC get_error;
} egl_api;

static int has_extension(const char *list, const char *name)
{
    size_t n = strlen(name);
    const char *p = list;
    while (p && (p = strstr(p, name)) != NULL) {
        if ((p == list || p[-1] == ' ') && (p[n] == ' ' || p[n] == '\0')) return 1;
        p += n;
    }
    return 0;
}

/* An OpenGL 4.3 core context on an initialised display, made current; 0 on success. */
static int egl_context_on(lensrt_gl *gl, const egl_api *egl, EGLDisplay dpy, char *why, size_t size)
{
    static const EGLint attribs[] = {EGL_CONTEXT_MAJOR_VERSION, 4, EGL_CONTEXT_MINOR_VERSION, 3,
                                     EGL_CONTEXT_OPENGL_PROFILE_MASK, EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT, EGL_NONE};
    EGLint major, minor;
    EGLContext c;
    if (!egl->initialize(dpy, &major, &minor)) {
        snprintf(why, size, "eglInitialize failed (0x%x)", (unsigned)egl->get_error());
        return 1;
    }
    if (!has_extension(egl->query_string(dpy, EGL_EXTENSIONS), "EGL_KHR_surfaceless_context") ||
        !egl->bind_api(EGL_OPENGL_API)) {
        snprintf(why, size, "no desktop OpenGL without a surface on this display");
        egl->terminate(dpy);
        return 1;
    }
    c = egl->create_context(dpy, (EGLConfig)0, EGL_NO_CONTEXT, attribs);
    if (c == EGL_NO_CONTEXT) {
        snprintf(why, size, "no OpenGL 4.3 core context (eglCreateContext error 0x%x)", (unsigned)egl->get_error());
        egl->terminate(dpy);
        return 1;
    }
    // Save the caller's context (lensrt_gl_release restores it), then make ours current
    gl->saved_display = gl->egl_get_current_display();
    gl->saved_context = gl->egl_get_current_context();
    gl->saved_draw = gl->egl_get_current_surface(EGL_DRAW);
    gl->saved_read = gl->egl_get_current_surface(EGL_READ);
    if (!egl->make_current(dpy, EGL_NO_SURFACE, EGL_NO_SURFACE, c)) {
        snprintf(why, size, "eglMakeCurrent failed (0x%x)", (unsigned)egl->get_error());
        egl->destroy_context(dpy, c);
        egl->terminate(dpy);
        return 1;
    }
    gl->display = dpy;
    gl->context = c;
    if (load_gl(gl, why, size)) {
        lensrt_gl_release(gl);
        egl->destroy_context(dpy, c);
        egl->terminate(dpy);
        gl->display = gl->context = NULL;
        return 1;
    }
    return 0;
}

static int open_egl(lensrt_gl *gl, lensrt_gl_platform platform, char *why, size_t size)
{
    egl_api egl;
    const char *client;
    memset(&egl, 0, sizeof egl);
    if (!gl->egl_lib) gl->egl_lib = dlopen("libEGL.so.1", RTLD_NOW | RTLD_LOCAL | RTLD_NODELETE);
    if (!gl->egl_lib) {
        snprintf(why, size, "libEGL.so.1 not found (%s)", dlerror());
        return 1;
    }
#define EGL_LOAD(field, type, name) egl.field = (type)lib_proc(gl->egl_lib, name)
    EGL_LOAD(get_proc_address, PFNEGLGETPROCADDRESSPROC, "eglGetProcAddress");
    EGL_LOAD(query_string, PFNEGLQUERYSTRINGPROC, "eglQueryString");
    EGL_LOAD(initialize, PFNEGLINITIALIZEPROC, "eglInitialize");
    EGL_LOAD(terminate, PFNEGLTERMINATEPROC, "eglTerminate");
    EGL_LOAD(bind_api, PFNEGLBINDAPIPROC, "eglBindAPI");
    EGL_LOAD(create_context, PFNEGLCREATECONTEXTPROC, "eglCreateContext");
    EGL_LOAD(destroy_context, PFNEGLDESTROYCONTEXTPROC, "eglDestroyContext");
    EGL_LOAD(make_current, PFNEGLMAKECURRENTPROC, "eglMakeCurrent");
    EGL_LOAD(get_error, PFNEGLGETERRORPROC, "eglGetError");
    gl->egl_get_proc_address = egl.get_proc_address;
    gl->egl_make_current = egl.make_current;
    gl->egl_destroy_context = egl.destroy_context;
    gl->egl_terminate = egl.terminate;
    EGL_LOAD(get_platform_display, PFNEGLGETPLATFORMDISPLAYEXTPROC, "eglGetPlatformDisplayEXT");
    gl->egl_get_current_context = (PFNEGLGETCURRENTCONTEXTPROC)lib_proc(gl->egl_lib, "eglGetCurrentContext");
    gl->egl_get_current_display = (PFNEGLGETCURRENTDISPLAYPROC)lib_proc(gl->egl_lib, "eglGetCurrentDisplay");
    gl->egl_get_current_surface = (PFNEGLGETCURRENTSURFACEPROC)lib_proc(gl->egl_lib, "eglGetCurrentSurface");
#undef EGL_LOAD
    if (!egl.get_proc_address || !egl.query_string || !egl.initialize || !egl.create_context || !egl.make_current ||
        !gl->egl_get_current_context || !gl->egl_get_current_display || !gl->egl_get_current_surface) {
        snprintf(why, size, "libEGL.so.1 lacks EGL 1.4 entry points");
        return 1;
    }
    // The platform extensions are client extensions (EGL 1.5 or EGL_EXT_client_extensions)
    client = egl.query_string(EGL_NO_DISPLAY, EGL_EXTENSIONS);
    if (!egl.get_platform_display)
        egl.get_platform_display = (PFNEGLGETPLATFORMDISPLAYEXTPROC)egl.get_proc_address("eglGetPlatformDisplayEXT");
    if (!client || !egl.get_platform_display) {
        snprintf(why, size, "EGL has no platform extensions");
        return 1;
    }
    if (platform == LENSRT_GL_PLATFORM_EGL_DEVICE) {
        EGLDeviceEXT devices[16];
        EGLint n = 0, i, pass;
        char reasons[768] = "";
        egl.query_devices = (PFNEGLQUERYDEVICESEXTPROC)egl.get_proc_address("eglQueryDevicesEXT");
        egl.query_device_string = (PFNEGLQUERYDEVICESTRINGEXTPROC)egl.get_proc_address("eglQueryDeviceStringEXT");
        if (!has_extension(client, "EGL_EXT_platform_device") || !egl.query_devices || !egl.query_device_string) {
            snprintf(why, size, "EGL has no device platform (EGL_EXT_platform_device)");
            return 1;
        }
        if (!egl.query_devices(16, devices, &n) || n == 0) {
            snprintf(why, size, "EGL lists no devices");
            return 1;
        }
        // Pass 0: hardware devices; pass 1: software ones (Mesa's llvmpipe device)
        for (pass = 0; pass < 2; pass++)
            for (i = 0; i < n; i++) {
                const char *ext = egl.query_device_string(devices[i], EGL_EXTENSIONS);
                int software = ext && has_extension(ext, "EGL_MESA_device_software");
                size_t used = strlen(reasons);
                EGLDisplay dpy;
                if (software != pass) continue;
                dpy = egl.get_platform_display(EGL_PLATFORM_DEVICE_EXT, devices[i], NULL);
                if (dpy == EGL_NO_DISPLAY) {
                    snprintf(reasons + used, sizeof reasons - used, "%sdevice %d: no display", used ? "; " : "", (int)i);
                    continue;
                }
                if (egl_context_on(gl, &egl, dpy, why, size) == 0) return 0;
                snprintf(reasons + used, sizeof reasons - used, "%sdevice %d: %s", used ? "; " : "", (int)i, why);
            }
        snprintf(why, size, "%s", reasons);
        return 1;
    }
    {
        EGLDisplay dpy;
        if (!has_extension(client, "EGL_MESA_platform_surfaceless")) {
            snprintf(why, size, "EGL has no surfaceless platform (EGL_MESA_platform_surfaceless)");
            return 1;
        }
        dpy = egl.get_platform_display(EGL_PLATFORM_SURFACELESS_MESA, (void *)EGL_DEFAULT_DISPLAY, NULL);
        if (dpy == EGL_NO_DISPLAY) {
            snprintf(why, size, "no surfaceless display");
            return 1;
        }
        return egl_context_on(gl, &egl, dpy, why, size);
    }
}

/* ------------------------------------------------------------------ GLFW ----- */

static void glfw_error(int code, const char *description)
{
    (void)code;
    (void)description; /* reported through glfwInit / glfwCreateWindow failing */
}

static int open_glfw(lensrt_gl *gl, char *why, size_t size)
{
    typedef int (*init_fn)(void);
    typedef void (*hint_fn)(int, int);
    typedef void *(*create_fn)(int, int, const char *, void *, void *);
    typedef void *(*set_error_fn)(void (*)(int, const char *));
    typedef int (*get_error_fn)(const char **);
    init_fn init;
    hint_fn hint;
    create_fn create;
    set_error_fn set_error;
    get_error_fn get_error;
    const char *description = NULL;
    gl->glfw_lib = dlopen("libglfw.so.3", RTLD_NOW | RTLD_LOCAL | RTLD_NODELETE);
    if (!gl->glfw_lib) {
        snprintf(why, size, "libglfw.so.3 not found");
        return 1;
    }
    init = (init_fn)lib_proc(gl->glfw_lib, "glfwInit");
    hint = (hint_fn)lib_proc(gl->glfw_lib, "glfwWindowHint");
    create = (create_fn)lib_proc(gl->glfw_lib, "glfwCreateWindow");
    set_error = (set_error_fn)lib_proc(gl->glfw_lib, "glfwSetErrorCallback");
    get_error = (get_error_fn)lib_proc(gl->glfw_lib, "glfwGetError");
    gl->glfw_make_context_current = (void (*)(void *))lib_proc(gl->glfw_lib, "glfwMakeContextCurrent");
    gl->glfw_get_current_context = (void *(*)(void))lib_proc(gl->glfw_lib, "glfwGetCurrentContext");
    gl->glfw_destroy_window = (void (*)(void *))lib_proc(gl->glfw_lib, "glfwDestroyWindow");
    gl->glfw_terminate = (void (*)(void))lib_proc(gl->glfw_lib, "glfwTerminate");
    gl->glfw_get_proc_address = (lensrt_gl_proc(*)(const char *))lib_proc(gl->glfw_lib, "glfwGetProcAddress");
    if (!init || !hint || !create || !set_error || !get_error || !gl->glfw_make_context_current ||
        !gl->glfw_get_current_context || !gl->glfw_destroy_window || !gl->glfw_terminate || !gl->glfw_get_proc_address) {
        snprintf(why, size, "libglfw.so.3 is older than GLFW 3.3");
        return 1;
    }
    set_error(glfw_error);
    if (!init()) {
        get_error(&description);
        snprintf(why, size, "glfwInit failed: %s (GLFW needs an X server: run under xvfb-run)",
                 description ? description : "no reason given");
        return 1;
    }
    hint(GLFW_VISIBLE, 0);
    hint(GLFW_CONTEXT_VERSION_MAJOR, 4);
    hint(GLFW_CONTEXT_VERSION_MINOR, 3);
    hint(GLFW_OPENGL_PROFILE, GLFW_OPENGL_CORE_PROFILE);
    hint(GLFW_OPENGL_FORWARD_COMPAT, 1);
    gl->window = create(16, 16, "lensrt", NULL, NULL);
    if (!gl->window) {
        get_error(&description);
        snprintf(why, size, "no OpenGL 4.3 core window: %s", description ? description : "no reason given");
        gl->glfw_terminate();
        return 1;
    }
    gl->saved_window = gl->glfw_get_current_context();
    gl->glfw_make_context_current(gl->window);
    if (load_gl(gl, why, size)) {
        gl->glfw_destroy_window(gl->window);
        gl->window = NULL;
        gl->glfw_terminate();
        return 1;
    }
    return 0;
}

/* ---------------------------------------------------------------- device ----- */

lensrt_result lensrt_gl_acquire(lensrt_context ctx, lensrt_gl *gl)
{
    if (gl->window) {
        gl->saved_window = gl->glfw_get_current_context();
        gl->glfw_make_context_current(gl->window);
        return LENSRT_SUCCESS;
    }
    gl->saved_display = gl->egl_get_current_display();
    gl->saved_context = gl->egl_get_current_context();
    gl->saved_draw = gl->egl_get_current_surface(EGL_DRAW);
    gl->saved_read = gl->egl_get_current_surface(EGL_READ);
    if (!gl->egl_make_current(gl->display, EGL_NO_SURFACE, EGL_NO_SURFACE, gl->context))
        return lensrt_fail(ctx, LENSRT_ERROR_DEVICE, "GL: eglMakeCurrent failed on %s", gl->renderer);
    return LENSRT_SUCCESS;
}

void lensrt_gl_release(lensrt_gl *gl)
{
    if (gl->window) {
        gl->glfw_make_context_current(gl->saved_window);
        return;
    }
    if (gl->saved_context != EGL_NO_CONTEXT && gl->saved_display != EGL_NO_DISPLAY)
        gl->egl_make_current(gl->saved_display, gl->saved_draw, gl->saved_read, gl->saved_context);
    else
        gl->egl_make_current(gl->display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
}

lensrt_result lensrt_gl_get(lensrt_context ctx, lensrt_gl **out)
{
    static const lensrt_gl_platform order[3] = {LENSRT_GL_PLATFORM_EGL_DEVICE, LENSRT_GL_PLATFORM_EGL_SURFACELESS,
                                                LENSRT_GL_PLATFORM_GLFW};
    char reasons[LENSRT_ERROR_SIZE] = "", why[512];
    lensrt_gl *gl;
    int i;
    *out = NULL;
    if (ctx->gl) {
        *out = ctx->gl;
        return LENSRT_SUCCESS;
    }
    gl = lensrt_calloc(ctx, 1, sizeof *gl);
    if (!gl) return lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_MEMORY, "GL: out of memory");
    for (i = 0; i < 3; i++) {
        lensrt_gl_platform p = order[i];
        size_t used = strlen(reasons);
        int failed;
        if (ctx->gl_platform != LENSRT_GL_PLATFORM_AUTO && ctx->gl_platform != p) continue;
        why[0] = '\0';
        failed = p == LENSRT_GL_PLATFORM_GLFW ? open_glfw(gl, why, sizeof why) : open_egl(gl, p, why, sizeof why);
        if (!failed) {
            gl->platform = p;
            lensrt_gl_release(gl);
            ctx->gl = gl;
            *out = gl;
            lensrt_log(ctx, LENSRT_LOG_INFO, "GL: %s, GL_RENDERER %s, GL_VERSION %s", platform_name(p), gl->renderer,
                       gl->version);
            return LENSRT_SUCCESS;
        }
        snprintf(reasons + used, sizeof reasons - used, "%s%s: %s", used ? "; " : "", platform_name(p), why);
        lensrt_log(ctx, LENSRT_LOG_INFO, "GL: %s: %s", platform_name(p), why);
    }
    if (gl->glfw_lib) dlclose(gl->glfw_lib);
    if (gl->egl_lib) dlclose(gl->egl_lib);
    lensrt_free(ctx, gl);
    return lensrt_fail(ctx, LENSRT_ERROR_NO_DEVICE, "GL: no OpenGL 4.3 core context (%s); the CPU device still works",
                       reasons);
}

void lensrt_gl_close(lensrt_context ctx)
{
    lensrt_gl *gl = ctx->gl;
    if (!gl) return;
    if (gl->window) {
        gl->glfw_destroy_window(gl->window);
        gl->glfw_terminate();
    } else if (gl->display) {
        gl->egl_destroy_context(gl->display, gl->context);
        gl->egl_terminate(gl->display);
    }
    if (gl->glfw_lib) dlclose(gl->glfw_lib);
    if (gl->egl_lib) dlclose(gl->egl_lib);
    lensrt_free(ctx, gl);
    ctx->gl = NULL;
}

lensrt_result lensrt_context_gl_info(lensrt_context ctx, lensrt_gl_info *out)
{
    lensrt_gl *gl;
    lensrt_gl_info info;
    lensrt_result res;
    if (!ctx || !out) return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_context_gl_info: NULL argument");
    if ((res = lensrt_struct_in(ctx, "lensrt_gl_info", out, &info, sizeof info)) != LENSRT_SUCCESS) return res;
    if ((res = lensrt_gl_get(ctx, &gl)) != LENSRT_SUCCESS) return res;
    info.platform = platform_name(gl->platform);
    info.renderer = gl->renderer;
    info.version = gl->version;
    info.software = gl->software;
    return lensrt_struct_out(ctx, "lensrt_gl_info", out, &info, sizeof info);
}
