/* The C tests' harness: CHECK counts every check and prints each failure with its file
 * and line (and the message), so one run lists every failure; main returns non-zero when
 * g_failures is. With lensrt.h included first: CHECK_RES (a call's result code against
 * the expected one, with the context's last error), CHECK_OK and CHECK_MSG. And
 * read_text, a whole file as a NUL-terminated string (malloc'd; NULL if unreadable);
 * stamp_table and load_stamped, a table edited by a test given its checksum line. */
#ifndef LENSRT_TEST_CHECK_H
#define LENSRT_TEST_CHECK_H

#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static int g_checks = 0, g_failures = 0;

static inline void check_at(int ok, const char *file, int line, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 4, 5)))
#endif
    ;
static inline void check_at(int ok, const char *file, int line, const char *fmt, ...)
{
    const char *base = strrchr(file, '/');
    ++g_checks;
    if (!ok) {
        va_list args;
        ++g_failures;
        fprintf(stderr, "%s:%d: FAILED: ", base ? base + 1 : file, line);
        va_start(args, fmt);
        vfprintf(stderr, fmt, args);
        va_end(args);
        fputc('\n', stderr);
    }
}
#define CHECK(cond, ...) check_at((cond) ? 1 : 0, __FILE__, __LINE__, __VA_ARGS__)

#ifdef LENSRT_H
static inline void check_res_at(int line, const char *file, const char *expr, lensrt_result got, lensrt_result want,
                                lensrt_context ctx)
{
    check_at(got == want, file, line, "%s: got %d (%s), expected %d (%s); last error: '%s'", expr, (int)got,
             lensrt_result_string(got), (int)want, lensrt_result_string(want),
             ctx ? lensrt_context_last_error(ctx) : "(no context)");
}
/* Call, then check the result code (the expression is printed on failure). */
#define CHECK_RES(ctx, want, call) check_res_at(__LINE__, __FILE__, #call, (call), (want), (ctx))
/* Call, then check it succeeded. */
#define CHECK_OK(ctx, call) CHECK_RES(ctx, LENSRT_SUCCESS, call)
/* The last error of ctx contains `needle`. */
#define CHECK_MSG(ctx, needle)                                                                     \
    CHECK(strstr(lensrt_context_last_error(ctx), (needle)) != NULL,                                \
          "last error '%s' does not contain '%s'", lensrt_context_last_error(ctx), (needle))
#endif

static inline char *read_text(const char *path, size_t *size)
{
    FILE *f = fopen(path, "rb");
    char *text = NULL;
    long n;
    *size = 0;
    if (!f) return NULL;
    if (fseek(f, 0, SEEK_END) == 0 && (n = ftell(f)) >= 0 && fseek(f, 0, SEEK_SET) == 0) {
        text = malloc((size_t)n + 1);
        if (text && fread(text, 1, (size_t)n, f) == (size_t)n) {
            text[n] = '\0';
            *size = (size_t)n;
        } else {
            free(text);
            text = NULL;
        }
    }
    fclose(f);
    return text;
}

/* A table text as lensfit would write it after a test's edit (version 4): a header of
 * version 3 made 4, an old checksum line made a comment, a final newline, then
 * `checksum crc32 <hex>` of all before it (a bitwise CRC-32, independent of the
 * library's table-driven one). Tests that change a table to reach one of the parser's
 * checks stamp it, as the checksum would refuse it first. The malloc'd copy's size goes
 * to *out_size (NULL on failure). */
static inline char *stamp_table(const char *text, size_t size, size_t *out_size)
{
    static const char v3[] = "lensfit-poly-table 3\n";
    char *out = malloc(size + 32);
    size_t n = size, start, k;
    uint32_t crc = 0xFFFFFFFFu;
    *out_size = 0;
    if (!out) return NULL;
    memcpy(out, text, size);
    if (n >= sizeof v3 - 1 && memcmp(out, v3, sizeof v3 - 1) == 0) out[sizeof v3 - 3] = '4';
    // An old checksum line (the last, or in the middle after a test appended lines)
    // becomes a comment, so that every line keeps its number
    for (start = 0; start < n; start++)
        if ((start == 0 || out[start - 1] == '\n') && n - start >= 15 && memcmp(out + start, "checksum crc32 ", 15) == 0)
            out[start] = '#';
    if (n && out[n - 1] != '\n') out[n++] = '\n';
    for (k = 0; k < n; k++) {
        int b;
        crc ^= (unsigned char)out[k];
        for (b = 0; b < 8; b++) crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
    }
    n += (size_t)sprintf(out + n, "checksum crc32 %08x\n", (unsigned)~crc);
    *out_size = n;
    return out;
}

#ifdef LENSRT_H
/* lensrt_lens_load_text of the stamped text (NULL text or ctx: passed on as they are). */
static inline lensrt_result load_stamped(lensrt_context ctx, const char *text, size_t size, const char *name,
                                         lensrt_lens *out)
{
    size_t n;
    char *stamped;
    lensrt_result res;
    if (!ctx || !text) return lensrt_lens_load_text(ctx, text, size, name, out);
    if (!(stamped = stamp_table(text, size, &n))) return LENSRT_ERROR_OUT_OF_MEMORY;
    res = lensrt_lens_load_text(ctx, stamped, n, name, out);
    free(stamped);
    return res;
}
#endif

#endif /* LENSRT_TEST_CHECK_H */
