/* What every source takes from a context: allocation through its hooks, error messages
 * (lensrt_fail) and the log, and the clock. Messages are formatted in the "C" locale
 * (c_numbers.h), whatever the host's LC_NUMERIC. The context itself (creation, hooks,
 * destruction) is core/context.c. */
#include "../c_numbers.h"
#include "../internal.h"

#include <stdio.h>
#include <string.h>
#include <time.h>

void *lensrt_alloc(lensrt_context ctx, size_t size)
{
    return ctx->allocator.alloc_fn(size ? size : 1, ctx->allocator.user_data);
}

void *lensrt_calloc(lensrt_context ctx, size_t count, size_t size)
{
    void *p;
    if (size && count > (size_t)-1 / size) return NULL;
    p = lensrt_alloc(ctx, count * size);
    if (p) memset(p, 0, (count * size) > 0 ? count * size : 1);
    return p;
}

void lensrt_free(lensrt_context ctx, void *ptr)
{
    if (ptr) ctx->allocator.free_fn(ptr, ctx->allocator.user_data);
}

lensrt_result lensrt_fail(lensrt_context ctx, lensrt_result result, const char *fmt, ...)
{
    va_list args;
    if (!ctx) return result;
    va_start(args, fmt);
    lensrt_vsnprintf_c(ctx->error, sizeof ctx->error, fmt, args);
    va_end(args);
    if (ctx->log_fn) ctx->log_fn(LENSRT_LOG_ERROR, ctx->error, ctx->user_data);
    return result;
}

void lensrt_log(lensrt_context ctx, lensrt_log_level level, const char *fmt, ...)
{
    char message[LENSRT_ERROR_SIZE];
    va_list args;
    if (!ctx || !ctx->log_fn) return;
    va_start(args, fmt);
    lensrt_vsnprintf_c(message, sizeof message, fmt, args);
    va_end(args);
    ctx->log_fn(level, message, ctx->user_data);
}

double lensrt_seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}
