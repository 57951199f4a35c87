/* Context: creation with its allocator and log hooks, destruction, the last error
 * message, result strings. What the other sources take from a context (allocation,
 * messages, the log) is in core/services.c, which this file uses like any other. */
#include "../internal.h"

#include <stdlib.h>
#include <string.h>

static void *default_alloc(size_t size, void *user_data)
{
    (void)user_data;
    return malloc(size);
}

static void default_free(void *ptr, void *user_data)
{
    (void)user_data;
    free(ptr);
}

const char *lensrt_result_string(lensrt_result result)
{
    switch (result) {
    case LENSRT_SUCCESS: return "success";
    case LENSRT_ERROR_INVALID_ARGUMENT: return "invalid argument";
    case LENSRT_ERROR_OUT_OF_MEMORY: return "out of memory";
    case LENSRT_ERROR_IO: return "input/output error";
    case LENSRT_ERROR_PARSE: return "malformed file";
    case LENSRT_ERROR_OUT_OF_DOMAIN: return "outside the fitted domain";
    case LENSRT_ERROR_INCOMPATIBLE: return "incompatible phasor sums";
    case LENSRT_ERROR_UNSUPPORTED: return "not supported by this build";
    case LENSRT_ERROR_CANCELLED: return "cancelled";
    case LENSRT_ERROR_NO_DEVICE: return "no GL device";
    case LENSRT_ERROR_DEVICE: return "GL device failure";
    }
    return "unknown result";
}

lensrt_result lensrt_context_create(const lensrt_context_init *init, lensrt_context *out)
{
    lensrt_context_init full;
    const lensrt_context_init *init_in = init;
    lensrt_context ctx;
    if (!out) return LENSRT_ERROR_INVALID_ARGUMENT;
    *out = NULL;
    // NULL means every default; a struct is read as far as its struct_size (there is no
    // context yet to hold a message: a bad struct_size is LENSRT_ERROR_INVALID_ARGUMENT)
    if (!init_in) {
        memset(&full, 0, sizeof full);
    } else {
        lensrt_result res = lensrt_struct_in(NULL, "lensrt_context_init", init_in, &full, sizeof full);
        if (res != LENSRT_SUCCESS) return res;
    }
    init = &full;
    // Allocator hooks come as a pair or not at all
    if ((init->alloc_fn == NULL) != (init->free_fn == NULL)) return LENSRT_ERROR_INVALID_ARGUMENT;
    if (init->threads < 0 || (unsigned)init->gl_platform > LENSRT_GL_PLATFORM_CALLER) return LENSRT_ERROR_INVALID_ARGUMENT;
    ctx = init->alloc_fn ? init->alloc_fn(sizeof *ctx, init->user_data) : malloc(sizeof *ctx);
    if (!ctx) return LENSRT_ERROR_OUT_OF_MEMORY;
    memset(ctx, 0, sizeof *ctx);
    ctx->allocator.alloc_fn = init->alloc_fn ? init->alloc_fn : default_alloc;
    ctx->allocator.free_fn = init->free_fn ? init->free_fn : default_free;
    ctx->allocator.user_data = init->user_data;
    ctx->log_fn = init->log_fn;
    ctx->user_data = init->user_data;
    ctx->threads = init->threads;
    ctx->gl_platform = init->gl_platform;
    *out = ctx;
    return LENSRT_SUCCESS;
}

void lensrt_context_destroy(lensrt_context ctx)
{
    if (!ctx) return;
    // The device goes first (its teardown uses the allocator and the log)
    if (ctx->device_destroy) ctx->device_destroy(ctx, ctx->device);
    ctx->device = NULL;
    ctx->device_destroy = NULL;
    ctx->allocator.free_fn(ctx, ctx->allocator.user_data);
}

#ifndef LENSRT_GL
lensrt_result lensrt_context_gl_info(lensrt_context ctx, lensrt_gl_info *out)
{
    lensrt_gl_info info;
    lensrt_result res;
    if (!ctx || !out) return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_context_gl_info: NULL argument");
    if ((res = lensrt_struct_in(ctx, "lensrt_gl_info", out, &info, sizeof info)) != LENSRT_SUCCESS) return res;
    return lensrt_fail(ctx, LENSRT_ERROR_UNSUPPORTED,
                       "GL: this build of lensrt has no GL path (configure with EGL and GL headers, LENSRT_WITH_GL=ON)");
}
#endif

const char *lensrt_context_last_error(lensrt_context ctx)
{
    return ctx ? ctx->error : "no context";
}
