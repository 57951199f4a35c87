/* What library sources compiled into a test (tests/runtime/CMakeLists.txt,
 * lensrt_internal_test) take from the rest of the library: the context's allocator (here
 * malloc, the context unused) and lensrt_fail (the message to stderr). Include in one
 * source of the test. */
#ifndef LENSRT_TEST_INTERNAL_STUBS_H
#define LENSRT_TEST_INTERNAL_STUBS_H

#include "../../runtime/src/internal.h"

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>

void *lensrt_alloc(lensrt_context ctx, size_t size)
{
    (void)ctx;
    return malloc(size);
}

void *lensrt_calloc(lensrt_context ctx, size_t count, size_t size)
{
    (void)ctx;
    return calloc(count, size);
}

void lensrt_free(lensrt_context ctx, void *ptr)
{
    (void)ctx;
    free(ptr);
}

lensrt_result lensrt_fail(lensrt_context ctx, lensrt_result result, const char *fmt, ...)
{
    va_list ap;
    (void)ctx;
    va_start(ap, fmt);
    vfprintf(stderr, fmt, ap);
    va_end(ap);
    fputc('\n', stderr);
    return result;
}

#endif /* LENSRT_TEST_INTERNAL_STUBS_H */
