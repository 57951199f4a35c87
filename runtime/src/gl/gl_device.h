/* The GL device (internal): a headless OpenGL 4.3 core context and its entry points.
 *
 * No GL library is linked: libEGL (or libglfw) is opened at run time and every entry
 * point is fetched through it into the device's own table (no globals), so the library
 * loads and the CPU path runs on machines without any GL. */
#ifndef LENSRT_GL_DEVICE_H
#define LENSRT_GL_DEVICE_H

#include "../c_numbers.h"
#include "../internal.h"

#include <EGL/egl.h>
#include <EGL/eglext.h>
#include <GL/glcorearb.h>

/* The GL entry points the compute path uses (the last three save and restore a caller's
 * state, LENSRT_GL_PLATFORM_CALLER). */
#define LENSRT_GL_FUNCTIONS(X)                                           \
    X(PFNGLGETSTRINGPROC, GetString)                                     \
    X(PFNGLGETINTEGERVPROC, GetIntegerv)                                 \
    X(PFNGLGETINTEGERI_VPROC, GetIntegeri_v)                             \
    X(PFNGLGETERRORPROC, GetError)                                       \
    X(PFNGLFINISHPROC, Finish)                                           \
    X(PFNGLCREATESHADERPROC, CreateShader)                               \
    X(PFNGLSHADERSOURCEPROC, ShaderSource)                               \
    X(PFNGLCOMPILESHADERPROC, CompileShader)                             \
    X(PFNGLGETSHADERIVPROC, GetShaderiv)                                 \
    X(PFNGLGETSHADERINFOLOGPROC, GetShaderInfoLog)                       \
    X(PFNGLDELETESHADERPROC, DeleteShader)                               \
    X(PFNGLCREATEPROGRAMPROC, CreateProgram)                             \
    X(PFNGLATTACHSHADERPROC, AttachShader)                               \
    X(PFNGLLINKPROGRAMPROC, LinkProgram)                                 \
    X(PFNGLGETPROGRAMIVPROC, GetProgramiv)                               \
    X(PFNGLGETPROGRAMINFOLOGPROC, GetProgramInfoLog)                     \
    X(PFNGLDELETEPROGRAMPROC, DeleteProgram)                             \
    X(PFNGLUSEPROGRAMPROC, UseProgram)                                   \
    X(PFNGLGETUNIFORMLOCATIONPROC, GetUniformLocation)                   \
    X(PFNGLUNIFORM1UIPROC, Uniform1ui)                                   \
    X(PFNGLUNIFORM4IPROC, Uniform4i)                                     \
    X(PFNGLGENBUFFERSPROC, GenBuffers)                                   \
    X(PFNGLDELETEBUFFERSPROC, DeleteBuffers)                             \
    X(PFNGLBINDBUFFERPROC, BindBuffer)                                   \
    X(PFNGLBINDBUFFERBASEPROC, BindBufferBase)                           \
    X(PFNGLBUFFERDATAPROC, BufferData)                                   \
    X(PFNGLBUFFERSUBDATAPROC, BufferSubData)                             \
    X(PFNGLGETBUFFERSUBDATAPROC, GetBufferSubData)                       \
    X(PFNGLDISPATCHCOMPUTEPROC, DispatchCompute)                         \
    X(PFNGLMEMORYBARRIERPROC, MemoryBarrier)                             \
    X(PFNGLGETINTEGER64I_VPROC, GetInteger64i_v)                         \
    X(PFNGLBINDBUFFERRANGEPROC, BindBufferRange)

typedef void (*lensrt_gl_proc)(void);

/* Shader storage binding points whose bindings a caller's context gets back (the
 * render uses fewer; drivers offer 8 to 96). */
#define LENSRT_GL_SAVED_BINDINGS 96

/* The caller's GL state that lensrt's calls change, saved by lensrt_gl_acquire and put
 * back by lensrt_gl_release (LENSRT_GL_PLATFORM_CALLER only). */
typedef struct lensrt_gl_state {
    GLint program;                  /* GL_CURRENT_PROGRAM */
    GLint buffer;                   /* GL_SHADER_STORAGE_BUFFER_BINDING */
    int n_bindings;                 /* indexed bindings saved */
    GLint binding[LENSRT_GL_SAVED_BINDINGS];
    GLint64 start[LENSRT_GL_SAVED_BINDINGS], size[LENSRT_GL_SAVED_BINDINGS];
} lensrt_gl_state;

typedef struct lensrt_gl_s {
    lensrt_gl_platform platform;
    char renderer[256], version[256];
    int software;
    int max_groups_x;               /* GL_MAX_COMPUTE_WORK_GROUP_COUNT[0] */
    void *egl_lib, *glfw_lib;       /* dlopen handles */
    EGLDisplay display;             /* EGL: ours, or the caller's (CALLER) */
    EGLContext context;
    int display_counted;            /* display got with EGL_TRACK_REFERENCES_KHR: our
                                       eglInitialize is a reference, eglTerminate drops it */
    void *window;                   /* GLFW */
    /* the thread's context before lensrt_gl_acquire, restored by lensrt_gl_release */
    EGLDisplay saved_display;
    EGLSurface saved_draw, saved_read;
    EGLContext saved_context;
    void *saved_window;
    lensrt_gl_state saved_state;    /* CALLER: the caller's GL state */
    /* EGL or GLFW entry points used after creation */
    PFNEGLGETPROCADDRESSPROC egl_get_proc_address;
    lensrt_gl_proc (*glfw_get_proc_address)(const char *name);
    PFNEGLMAKECURRENTPROC egl_make_current;
    PFNEGLGETCURRENTCONTEXTPROC egl_get_current_context;
    PFNEGLGETCURRENTDISPLAYPROC egl_get_current_display;
    PFNEGLGETCURRENTSURFACEPROC egl_get_current_surface;
    PFNEGLDESTROYCONTEXTPROC egl_destroy_context;
    PFNEGLTERMINATEPROC egl_terminate;
    void (*glfw_make_context_current)(void *window);
    void *(*glfw_get_current_context)(void);
    void (*glfw_destroy_window)(void *window);
#define LENSRT_GL_MEMBER(type, name) type name;
    LENSRT_GL_FUNCTIONS(LENSRT_GL_MEMBER)
#undef LENSRT_GL_MEMBER
} lensrt_gl_s;

typedef struct lensrt_gl_s lensrt_gl;

/* The context's device, made on first use (NULL and an error when there is none). The
 * device tears itself down through the context's device hook (lensrt_context_destroy). */
lensrt_result lensrt_gl_get(lensrt_context ctx, lensrt_gl **out);
/* Make the device current on this thread (saving the thread's EGL or GLFW context), and
 * undo. With LENSRT_GL_PLATFORM_CALLER: check that the caller's context is current, and
 * save the caller's GL state that lensrt changes; release puts it back. */
lensrt_result lensrt_gl_acquire(lensrt_context ctx, lensrt_gl *gl);
void lensrt_gl_release(lensrt_gl *gl);

#endif /* LENSRT_GL_DEVICE_H */
