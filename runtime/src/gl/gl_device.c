/* The GL device: a headless OpenGL 4.3 core context, found in this order (AUTO):
 *   1. the EGL device platform (EGL_EXT_platform_device), non-software devices first:
 *      NVIDIA's driver and Mesa's hardware drivers offer their GPUs here;
 *   2. Mesa's surfaceless platform (EGL_MESA_platform_surfaceless): llvmpipe on a
 *      machine without a GPU;
 *   3. GLFW 3.3 with a hidden window, under an X server (xvfb-run on a server).
 * Or the caller's own EGL context, current on the calling thread (CALLER).
 * Every library is opened at run time; the reason each platform failed goes into the
 * error message.
 *
 * lensrt lives inside host programs (renderers) that may use EGL and GLFW themselves, so
 * it leaves everything process-wide as it found it:
 *   - EGL displays are per-process singletons: eglGetPlatformDisplay returns the same
 *     display to everyone in the process who asks for the same platform and native
 *     display, and eglTerminate on it destroys every context of it that is not current
 *     at that moment, the host's and other lensrt contexts' included (EGL 1.5, 3.2). EGL
 *     keeps no count of its users, so lensrt never terminates a display: it destroys its
 *     own context and leaves the display initialised (initialising an initialised
 *     display is a no-op, so nothing piles up; the driver frees it at exit). Only with
 *     EGL_KHR_display_reference does lensrt ask for a counted display
 *     (EGL_TRACK_REFERENCES_KHR): there each eglInitialize is a reference and
 *     eglTerminate drops lensrt's alone. Mesa 22 (Debian 12) does not offer it.
 *   - The thread's current EGL context and bound API (eglBindAPI is per thread) are
 *     restored after each lensrt call.
 *   - GLFW is initialised once per process and glfwTerminate destroys every window and
 *     context of the process, with no count of users either: lensrt never calls it
 *     (whether the host initialised GLFW before lensrt, or starts using it after, its
 *     windows survive lensrt_context_destroy); lensrt destroys its own hidden window.
 *     GLFW's error callback is process-wide: lensrt installs its own only while it
 *     calls glfwInit and glfwCreateWindow, and puts the previous one back.
 *   - CALLER: lensrt makes no context current, creates and destroys no display or
 *     context, and restores the GL state its calls change (the current program, the
 *     shader storage buffer bindings). GL errors have no per-user queue: lensrt reads
 *     glGetError after its own work, which consumes any error the caller left pending. */
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
           : p == LENSRT_GL_PLATFORM_EGL_SURFACELESS ? "egl-surfaceless"
           : p == LENSRT_GL_PLATFORM_CALLER ? "caller" : "glfw";
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

/* Fetch the GL entry points and check that the current context is desktop OpenGL 4.3 or
 * later (compute shaders); 0 on success, else a reason in why. */
static int load_gl(lensrt_gl *gl, char *why, size_t size)
{
    GLint major = 0, minor = 0;
    const char *renderer, *version;
    int i;
#define LENSRT_GL_LOAD(type, name)                                                \
    if (!(gl->name = (type)get_proc(gl, "gl" #name))) {                                    \
        snprintf(why, size, "no entry point gl%s", #name);                        \
        return 1;                                                                 \
    }
    LENSRT_GL_FUNCTIONS(LENSRT_GL_LOAD)
#undef LENSRT_GL_LOAD
    // Errors left pending (a caller's context) would be taken for ours below
    for (i = 0; i < 16 && gl->GetError() != GL_NO_ERROR; i++) continue;
    renderer = (const char *)gl->GetString(GL_RENDERER);
    version = (const char *)gl->GetString(GL_VERSION);
    if (!version) {
        snprintf(why, size, "glGetString(GL_VERSION) failed: no usable GL context is current");
        return 1;
    }
    if (strncmp(version, "OpenGL ES", 9) == 0) {
        snprintf(why, size, "%s on %s is OpenGL ES; the compute shaders need desktop OpenGL 4.3", version,
                 renderer ? renderer : "?");
        return 1;
    }
    gl->GetIntegerv(GL_MAJOR_VERSION, &major);
    gl->GetIntegerv(GL_MINOR_VERSION, &minor);
    if (major * 10 + minor < 43) {
        snprintf(why, size, "OpenGL %d.%d on %s, compute shaders need 4.3", major, minor, renderer ? renderer : "?");
        return 1;
    }
    snprintf(gl->renderer, sizeof gl->renderer, "%s", renderer ? renderer : "unknown");
    snprintf(gl->version, sizeof gl->version, "%s", version);
    gl->software = strstr(gl->renderer, "llvmpipe") || strstr(gl->renderer, "softpipe") ||
                   strstr(gl->renderer, "swrast") || strstr(gl->renderer, "Software");
    major = 0;
    gl->GetIntegeri_v(GL_MAX_COMPUTE_WORK_GROUP_COUNT, 0, &major);
    gl->max_groups_x = major > 0 ? major : 65535;
    if (gl->GetError() != GL_NO_ERROR) {
        snprintf(why, size, "GL errors while querying the compute limits of %s", gl->renderer);
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
    PFNEGLQUERYAPIPROC query_api;
    PFNEGLCREATECONTEXTPROC create_context;
    PFNEGLDESTROYCONTEXTPROC destroy_context;
    PFNEGLQUERYCONTEXTPROC query_context;
    PFNEGLMAKECURRENTPROC make_current;
    PFNEGLGETERRORPROC get_error;
    int counted;            /* displays are asked for with EGL_TRACK_REFERENCES_KHR */
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

/* Give up a display lensrt initialised: only a counted display (EGL_KHR_display_reference)
 * is terminated, which drops lensrt's reference alone; any other stays initialised (see
 * the top of this file: it may be someone else's too). */
static void egl_let_go(const egl_api *egl, EGLDisplay dpy)
{
    if (egl->counted) egl->terminate(dpy);
}

/* An OpenGL 4.3 core context on a display, made current; 0 on success. The thread's
 * bound API is put back after (eglBindAPI is per-thread state the host may rely on). */
static int egl_context_on(lensrt_gl *gl, const egl_api *egl, EGLDisplay dpy, char *why, size_t size)
{
    static const EGLint attribs[] = {EGL_CONTEXT_MAJOR_VERSION, 4, EGL_CONTEXT_MINOR_VERSION, 3,
                                     EGL_CONTEXT_OPENGL_PROFILE_MASK, EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT, EGL_NONE};
    EGLint major, minor;
    EGLenum api;
    EGLContext c;
    if (!egl->initialize(dpy, &major, &minor)) {
        snprintf(why, size, "eglInitialize failed (0x%x)", (unsigned)egl->get_error());
        return 1;
    }
    if (!has_extension(egl->query_string(dpy, EGL_EXTENSIONS), "EGL_KHR_surfaceless_context")) {
        snprintf(why, size, "no desktop OpenGL without a surface on this display");
        egl_let_go(egl, dpy);
        return 1;
    }
    api = egl->query_api();
    if (!egl->bind_api(EGL_OPENGL_API)) {
        snprintf(why, size, "no desktop OpenGL on this display (eglBindAPI error 0x%x)", (unsigned)egl->get_error());
        egl_let_go(egl, dpy);
        return 1;
    }
    c = egl->create_context(dpy, (EGLConfig)0, EGL_NO_CONTEXT, attribs);
    if (api != EGL_OPENGL_API) egl->bind_api(api);
    if (c == EGL_NO_CONTEXT) {
        snprintf(why, size, "no OpenGL 4.3 core context (eglCreateContext error 0x%x)", (unsigned)egl->get_error());
        egl_let_go(egl, dpy);
        return 1;
    }
    // Save the thread's context (lensrt_gl_release restores it), then make ours current
    gl->saved_display = gl->egl_get_current_display();
    gl->saved_context = gl->egl_get_current_context();
    gl->saved_draw = gl->egl_get_current_surface(EGL_DRAW);
    gl->saved_read = gl->egl_get_current_surface(EGL_READ);
    if (!egl->make_current(dpy, EGL_NO_SURFACE, EGL_NO_SURFACE, c)) {
        snprintf(why, size, "eglMakeCurrent failed (0x%x)", (unsigned)egl->get_error());
        egl->destroy_context(dpy, c);
        egl_let_go(egl, dpy);
        return 1;
    }
    gl->display = dpy;
    gl->context = c;
    if (load_gl(gl, why, size)) {
        lensrt_gl_release(gl);
        egl->destroy_context(dpy, c);
        egl_let_go(egl, dpy);
        gl->display = gl->context = NULL;
        return 1;
    }
    gl->display_counted = egl->counted;
    return 0;
}

/* Open libEGL and fetch the entry points; 0 on success. */
static int load_egl(lensrt_gl *gl, egl_api *egl, char *why, size_t size)
{
    memset(egl, 0, sizeof *egl);
    if (!gl->egl_lib) gl->egl_lib = dlopen("libEGL.so.1", RTLD_NOW | RTLD_LOCAL | RTLD_NODELETE);
    if (!gl->egl_lib) {
        snprintf(why, size, "libEGL.so.1 not found (%s)", dlerror());
        return 1;
    }
#define EGL_LOAD(field, type, name) egl->field = (type)lib_proc(gl->egl_lib, name)
    EGL_LOAD(get_proc_address, PFNEGLGETPROCADDRESSPROC, "eglGetProcAddress");
    EGL_LOAD(query_string, PFNEGLQUERYSTRINGPROC, "eglQueryString");
    EGL_LOAD(initialize, PFNEGLINITIALIZEPROC, "eglInitialize");
    EGL_LOAD(terminate, PFNEGLTERMINATEPROC, "eglTerminate");
    EGL_LOAD(bind_api, PFNEGLBINDAPIPROC, "eglBindAPI");
    EGL_LOAD(query_api, PFNEGLQUERYAPIPROC, "eglQueryAPI");
    EGL_LOAD(create_context, PFNEGLCREATECONTEXTPROC, "eglCreateContext");
    EGL_LOAD(destroy_context, PFNEGLDESTROYCONTEXTPROC, "eglDestroyContext");
    EGL_LOAD(query_context, PFNEGLQUERYCONTEXTPROC, "eglQueryContext");
    EGL_LOAD(make_current, PFNEGLMAKECURRENTPROC, "eglMakeCurrent");
    EGL_LOAD(get_error, PFNEGLGETERRORPROC, "eglGetError");
    EGL_LOAD(get_platform_display, PFNEGLGETPLATFORMDISPLAYEXTPROC, "eglGetPlatformDisplayEXT");
#undef EGL_LOAD
    gl->egl_get_proc_address = egl->get_proc_address;
    gl->egl_make_current = egl->make_current;
    gl->egl_destroy_context = egl->destroy_context;
    gl->egl_terminate = egl->terminate;
    gl->egl_get_current_context = (PFNEGLGETCURRENTCONTEXTPROC)lib_proc(gl->egl_lib, "eglGetCurrentContext");
    gl->egl_get_current_display = (PFNEGLGETCURRENTDISPLAYPROC)lib_proc(gl->egl_lib, "eglGetCurrentDisplay");
    gl->egl_get_current_surface = (PFNEGLGETCURRENTSURFACEPROC)lib_proc(gl->egl_lib, "eglGetCurrentSurface");
    if (!egl->get_proc_address || !egl->query_string || !egl->initialize || !egl->terminate || !egl->bind_api ||
        !egl->query_api || !egl->create_context || !egl->destroy_context || !egl->query_context ||
        !egl->make_current || !egl->get_error || !gl->egl_get_current_context || !gl->egl_get_current_display ||
        !gl->egl_get_current_surface) {
        snprintf(why, size, "libEGL.so.1 lacks EGL 1.4 entry points");
        return 1;
    }
    return 0;
}

static int open_egl(lensrt_gl *gl, lensrt_gl_platform platform, char *why, size_t size)
{
    /* A counted display where EGL offers one (EGL_KHR_display_reference) */
    static const EGLint counted_attribs[] = {EGL_TRACK_REFERENCES_KHR, EGL_TRUE, EGL_NONE};
    egl_api egl;
    const char *client;
    const EGLint *attribs;
    if (load_egl(gl, &egl, why, size)) return 1;
    // The platform extensions are client extensions (EGL 1.5 or EGL_EXT_client_extensions)
    client = egl.query_string(EGL_NO_DISPLAY, EGL_EXTENSIONS);
    if (!egl.get_platform_display)
        egl.get_platform_display = (PFNEGLGETPLATFORMDISPLAYEXTPROC)egl.get_proc_address("eglGetPlatformDisplayEXT");
    if (!client || !egl.get_platform_display) {
        snprintf(why, size, "EGL has no platform extensions");
        return 1;
    }
    egl.counted = has_extension(client, "EGL_KHR_display_reference");
    attribs = egl.counted ? counted_attribs : NULL;
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
                dpy = egl.get_platform_display(EGL_PLATFORM_DEVICE_EXT, devices[i], attribs);
                if (dpy == EGL_NO_DISPLAY) {
                    snprintf(reasons + used, sizeof reasons - used, "%sdevice %d: no display", used ? "; " : "", (int)i);
                    continue;
                }
                if (egl_context_on(gl, &egl, dpy, why, size) == 0) return 0;
                snprintf(reasons + used, sizeof reasons - used, "%sdevice %d: %s", used ? "; " : "", (int)i, why);
            }
        {
            // Every device's reason, cut to the caller's buffer (size is never 0 here)
            size_t len = strlen(reasons);
            if (len >= size) len = size - 1;
            memcpy(why, reasons, len);
            why[len] = '\0';
        }
        return 1;
    }
    {
        EGLDisplay dpy;
        if (!has_extension(client, "EGL_MESA_platform_surfaceless")) {
            snprintf(why, size, "EGL has no surfaceless platform (EGL_MESA_platform_surfaceless)");
            return 1;
        }
        dpy = egl.get_platform_display(EGL_PLATFORM_SURFACELESS_MESA, (void *)EGL_DEFAULT_DISPLAY, attribs);
        if (dpy == EGL_NO_DISPLAY) {
            snprintf(why, size, "no surfaceless display");
            return 1;
        }
        return egl_context_on(gl, &egl, dpy, why, size);
    }
}

/* ---------------------------------------------------------------- caller ----- */

/* The caller's EGL context, current on this thread: checked, never made current,
 * created or destroyed by lensrt. 0 on success. */
static int open_caller(lensrt_gl *gl, char *why, size_t size)
{
    egl_api egl;
    EGLint client_type = 0;
    if (load_egl(gl, &egl, why, size)) return 1;
    gl->context = gl->egl_get_current_context();
    gl->display = gl->egl_get_current_display();
    if (gl->context == EGL_NO_CONTEXT || gl->display == EGL_NO_DISPLAY) {
        snprintf(why, size, "no EGL context is current on this thread: the caller's context must be current when "
                            "the GL device is first used (and during every call on GL renders)");
        gl->context = gl->display = NULL;
        return 1;
    }
    if (!egl.query_context(gl->display, gl->context, EGL_CONTEXT_CLIENT_TYPE, &client_type) ||
        client_type != EGL_OPENGL_API) {
        snprintf(why, size, "the current EGL context is not desktop OpenGL (client type 0x%x); the compute shaders "
                            "need OpenGL 4.3", (unsigned)client_type);
        gl->context = gl->display = NULL;
        return 1;
    }
    // What lensrt_gl_get's release puts back: the caller's state as it is now
    gl->saved_state.n_bindings = 0;
    if (load_gl(gl, why, size)) {
        gl->context = gl->display = NULL;
        return 1;
    }
    gl->GetIntegerv(GL_CURRENT_PROGRAM, &gl->saved_state.program);
    gl->GetIntegerv(GL_SHADER_STORAGE_BUFFER_BINDING, &gl->saved_state.buffer);
    return 0;
}

/* Save the caller's GL state that lensrt's calls change. */
static void save_state(lensrt_gl *gl)
{
    lensrt_gl_state *st = &gl->saved_state;
    GLint n = 0, i;
    gl->GetIntegerv(GL_CURRENT_PROGRAM, &st->program);
    gl->GetIntegerv(GL_SHADER_STORAGE_BUFFER_BINDING, &st->buffer);
    gl->GetIntegerv(GL_MAX_SHADER_STORAGE_BUFFER_BINDINGS, &n);
    st->n_bindings = n < 0 ? 0 : n > LENSRT_GL_SAVED_BINDINGS ? LENSRT_GL_SAVED_BINDINGS : (int)n;
    for (i = 0; i < st->n_bindings; i++) {
        st->binding[i] = 0;
        st->start[i] = st->size[i] = 0;
        gl->GetIntegeri_v(GL_SHADER_STORAGE_BUFFER_BINDING, (GLuint)i, &st->binding[i]);
        gl->GetInteger64i_v(GL_SHADER_STORAGE_BUFFER_START, (GLuint)i, &st->start[i]);
        gl->GetInteger64i_v(GL_SHADER_STORAGE_BUFFER_SIZE, (GLuint)i, &st->size[i]);
    }
}

/* Put the caller's GL state back. A binding of size 0 was made by glBindBufferBase (the
 * whole buffer), any other by glBindBufferRange. */
static void restore_state(lensrt_gl *gl)
{
    const lensrt_gl_state *st = &gl->saved_state;
    int i;
    for (i = 0; i < st->n_bindings; i++) {
        if (st->binding[i] == 0 || st->size[i] == 0)
            gl->BindBufferBase(GL_SHADER_STORAGE_BUFFER, (GLuint)i, (GLuint)st->binding[i]);
        else
            gl->BindBufferRange(GL_SHADER_STORAGE_BUFFER, (GLuint)i, (GLuint)st->binding[i], (GLintptr)st->start[i],
                                (GLsizeiptr)st->size[i]);
    }
    gl->BindBuffer(GL_SHADER_STORAGE_BUFFER, (GLuint)st->buffer);
    gl->UseProgram((GLuint)st->program);
}

/* ------------------------------------------------------------------ GLFW ----- */

static void glfw_error(int code, const char *description)
{
    (void)code;
    (void)description; /* reported through glfwGetError after glfwInit / glfwCreateWindow fail */
}

static int open_glfw(lensrt_gl *gl, char *why, size_t size)
{
    typedef void (*error_fn)(int, const char *);
    typedef int (*init_fn)(void);
    typedef void (*hint_fn)(int, int);
    typedef void *(*create_fn)(int, int, const char *, void *, void *);
    typedef error_fn (*set_error_fn)(error_fn);
    typedef int (*get_error_fn)(const char **);
    typedef void (*default_hints_fn)(void);
    init_fn init;
    hint_fn hint;
    create_fn create;
    set_error_fn set_error;
    get_error_fn get_error;
    default_hints_fn default_hints;
    error_fn host_callback;
    const char *description = NULL;
    char reason[256] = "";
    gl->glfw_lib = dlopen("libglfw.so.3", RTLD_NOW | RTLD_LOCAL | RTLD_NODELETE);
    if (!gl->glfw_lib) {
        snprintf(why, size, "libglfw.so.3 not found");
        return 1;
    }
    init = (init_fn)lib_proc(gl->glfw_lib, "glfwInit");
    hint = (hint_fn)lib_proc(gl->glfw_lib, "glfwWindowHint");
    default_hints = (default_hints_fn)lib_proc(gl->glfw_lib, "glfwDefaultWindowHints");
    create = (create_fn)lib_proc(gl->glfw_lib, "glfwCreateWindow");
    set_error = (set_error_fn)lib_proc(gl->glfw_lib, "glfwSetErrorCallback");
    get_error = (get_error_fn)lib_proc(gl->glfw_lib, "glfwGetError");
    gl->glfw_make_context_current = (void (*)(void *))lib_proc(gl->glfw_lib, "glfwMakeContextCurrent");
    gl->glfw_get_current_context = (void *(*)(void))lib_proc(gl->glfw_lib, "glfwGetCurrentContext");
    gl->glfw_destroy_window = (void (*)(void *))lib_proc(gl->glfw_lib, "glfwDestroyWindow");
    gl->glfw_get_proc_address = (lensrt_gl_proc(*)(const char *))lib_proc(gl->glfw_lib, "glfwGetProcAddress");
    if (!init || !hint || !default_hints || !create || !set_error || !get_error || !gl->glfw_make_context_current ||
        !gl->glfw_get_current_context || !gl->glfw_destroy_window || !gl->glfw_get_proc_address) {
        snprintf(why, size, "libglfw.so.3 is older than GLFW 3.3");
        gl->glfw_get_proc_address = NULL;
        return 1;
    }
    // Our error callback only while we call GLFW here (errors come back through
    // glfwGetError); the host's, if any, is put back before anything else happens
    host_callback = set_error(glfw_error);
    // glfwInit is a no-op when the host initialised GLFW already. It is never undone:
    // glfwTerminate would destroy every window of the process (see the top of the file)
    if (!init()) {
        get_error(&description);
        snprintf(reason, sizeof reason, "glfwInit failed: %s (GLFW needs an X server: run under xvfb-run)",
                 description ? description : "no reason given");
    } else {
        // Window hints are process-wide too and cannot be read back: ours for our
        // window, then GLFW's defaults (a host sets its hints before each window)
        hint(GLFW_VISIBLE, 0);
        hint(GLFW_CONTEXT_VERSION_MAJOR, 4);
        hint(GLFW_CONTEXT_VERSION_MINOR, 3);
        hint(GLFW_OPENGL_PROFILE, GLFW_OPENGL_CORE_PROFILE);
        hint(GLFW_OPENGL_FORWARD_COMPAT, 1);
        gl->window = create(16, 16, "lensrt", NULL, NULL);
        if (!gl->window) {
            get_error(&description);
            snprintf(reason, sizeof reason, "no OpenGL 4.3 core window: %s",
                     description ? description : "no reason given");
        }
        default_hints();
    }
    set_error(host_callback);
    if (!gl->window) {
        snprintf(why, size, "%s", reason);
        gl->glfw_get_proc_address = NULL;
        return 1;
    }
    gl->saved_window = gl->glfw_get_current_context();
    gl->glfw_make_context_current(gl->window);
    if (load_gl(gl, why, size)) {
        gl->glfw_make_context_current(gl->saved_window);
        gl->glfw_destroy_window(gl->window);
        gl->window = NULL;
        gl->glfw_get_proc_address = NULL;
        return 1;
    }
    return 0;
}

/* ---------------------------------------------------------------- device ----- */

lensrt_result lensrt_gl_acquire(lensrt_context ctx, lensrt_gl *gl)
{
    if (gl->platform == LENSRT_GL_PLATFORM_CALLER) {
        // The caller's own context must be the current one; nothing is made current
        if (gl->egl_get_current_context() != gl->context)
            return lensrt_fail(ctx, LENSRT_ERROR_DEVICE,
                               "GL: platform caller: the caller's EGL context (%p, on %s) is not current on this "
                               "thread; keep it current during calls on GL renders",
                               (void *)gl->context, gl->renderer);
        save_state(gl);
        return LENSRT_SUCCESS;
    }
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
    if (gl->platform == LENSRT_GL_PLATFORM_CALLER) {
        restore_state(gl);
        return;
    }
    if (gl->window) {
        gl->glfw_make_context_current(gl->saved_window);
        return;
    }
    if (gl->saved_context != EGL_NO_CONTEXT && gl->saved_display != EGL_NO_DISPLAY)
        gl->egl_make_current(gl->saved_display, gl->saved_draw, gl->saved_read, gl->saved_context);
    else
        gl->egl_make_current(gl->display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
}

/* The context's device hook: destroy what lensrt made, and nothing process-wide. */
static void gl_destroy(lensrt_context ctx, void *device)
{
    lensrt_gl *gl = device;
    if (!gl) return;
    if (gl->platform == LENSRT_GL_PLATFORM_CALLER) {
        /* the caller's context and display: not ours to touch */
    } else if (gl->window) {
        gl->glfw_destroy_window(gl->window);
    } else if (gl->display) {
        gl->egl_destroy_context(gl->display, gl->context);
        if (gl->display_counted) gl->egl_terminate(gl->display); /* our reference only */
    }
    if (gl->glfw_lib) dlclose(gl->glfw_lib);
    if (gl->egl_lib) dlclose(gl->egl_lib);
    lensrt_free(ctx, gl);
}

lensrt_result lensrt_gl_get(lensrt_context ctx, lensrt_gl **out)
{
    static const lensrt_gl_platform order[4] = {LENSRT_GL_PLATFORM_EGL_DEVICE, LENSRT_GL_PLATFORM_EGL_SURFACELESS,
                                                LENSRT_GL_PLATFORM_GLFW, LENSRT_GL_PLATFORM_CALLER};
    char reasons[LENSRT_ERROR_SIZE] = "", why[512];
    lensrt_gl *gl;
    int i;
    *out = NULL;
    if (ctx->device) {
        *out = ctx->device;
        return LENSRT_SUCCESS;
    }
    gl = lensrt_calloc(ctx, 1, sizeof *gl);
    if (!gl) return lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_MEMORY, "GL: out of memory");
    for (i = 0; i < 4; i++) {
        lensrt_gl_platform p = order[i];
        size_t used = strlen(reasons);
        int failed;
        // AUTO tries the first three; the caller's context only when asked for
        if (ctx->gl_platform == LENSRT_GL_PLATFORM_AUTO ? p == LENSRT_GL_PLATFORM_CALLER : ctx->gl_platform != p)
            continue;
        why[0] = '\0';
        failed = p == LENSRT_GL_PLATFORM_GLFW     ? open_glfw(gl, why, sizeof why)
                 : p == LENSRT_GL_PLATFORM_CALLER ? open_caller(gl, why, sizeof why)
                                                  : open_egl(gl, p, why, sizeof why);
        if (!failed) {
            gl->platform = p;
            lensrt_gl_release(gl);
            // The context tears the device down through this hook (core/context.c knows no GL)
            ctx->device = gl;
            ctx->device_destroy = gl_destroy;
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
