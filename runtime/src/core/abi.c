/* The ABI rules of lensrt.h: versioned structs read and written by their struct_size,
 * and the library's version. */
#include "../internal.h"

#include <stdio.h>
#include <string.h>

#define STR2(x) #x
#define STR(x) STR2(x)

uint32_t lensrt_version(void) { return LENSRT_VERSION; }

const char *lensrt_version_string(void)
{
    return STR(LENSRT_VERSION_MAJOR) "." STR(LENSRT_VERSION_MINOR) "." STR(LENSRT_VERSION_PATCH);
}

/* Whether every byte of p[0 .. n) is zero. */
static int all_zero(const unsigned char *p, size_t n)
{
    size_t i;
    for (i = 0; i < n; i++)
        if (p[i]) return 0;
    return 1;
}

lensrt_result lensrt_struct_in(lensrt_context ctx, const char *what, const void *src, void *full,
                               size_t full_size)
{
    size_t size;
    memset(full, 0, full_size);
    if (!src) return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "%s: NULL pointer", what);
    memcpy(&size, src, sizeof size);
    // The caller's struct must at least hold its size; 0 means it was zeroed without
    // its INIT macro, so we cannot know how much of it there is
    if (size < sizeof(size_t))
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "%s: struct_size is %zu; set it to sizeof the struct (use its LENSRT_*_INIT macro)",
                           what, size);
    // A newer caller's fields this library does not know must be zero (their defaults)
    if (size > full_size && !all_zero((const unsigned char *)src + full_size, size - full_size))
        return lensrt_fail(ctx, LENSRT_ERROR_UNSUPPORTED,
                           "%s: struct_size %zu is larger than this library's %zu (lensrt %s) and the "
                           "fields it does not know are set; use a newer library", what, size, full_size,
                           lensrt_version_string());
    // Fields an older caller does not have keep their defaults (zero)
    memcpy(full, src, size < full_size ? size : full_size);
    return LENSRT_SUCCESS;
}

lensrt_result lensrt_struct_out(lensrt_context ctx, const char *what, void *dst, const void *full,
                                size_t full_size)
{
    size_t size;
    if (!dst) return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "%s: NULL pointer", what);
    memcpy(&size, dst, sizeof size);
    if (size < sizeof(size_t))
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "%s: struct_size is %zu; set it to sizeof the struct (use its LENSRT_*_INIT macro)",
                           what, size);
    // Write only what the caller's struct holds, and leave its struct_size as it was;
    // the bytes of a newer caller's struct past ours are zeroed (their defaults)
    memcpy((unsigned char *)dst + sizeof size, (const unsigned char *)full + sizeof size,
           (size < full_size ? size : full_size) - sizeof size);
    if (size > full_size) memset((unsigned char *)dst + full_size, 0, size - full_size);
    return LENSRT_SUCCESS;
}

lensrt_result lensrt_array_in(lensrt_context ctx, const char *what, const void *src, size_t count, void *full,
                              size_t full_size)
{
    const unsigned char *p = src;
    size_t stride, k;
    lensrt_result res;
    if (count == 0) return LENSRT_SUCCESS;
    if (!src) return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "%s: NULL array of %zu", what, count);
    // The first element's struct_size is the stride; every element must say the same
    memcpy(&stride, p, sizeof stride);
    for (k = 0; k < count; k++) {
        size_t size;
        char name[160];
        memcpy(&size, p + k * stride, sizeof size);
        snprintf(name, sizeof name, "%s[%zu]", what, k);
        if (size != stride)
            return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                               "%s: struct_size %zu differs from element 0's %zu (the array's stride)", name,
                               size, stride);
        if ((res = lensrt_struct_in(ctx, name, p + k * stride, (unsigned char *)full + k * full_size, full_size)) !=
            LENSRT_SUCCESS)
            return res;
    }
    return LENSRT_SUCCESS;
}
