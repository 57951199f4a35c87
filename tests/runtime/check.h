/* The C tests' harness: CHECK counts every check and prints each failure with its file
 * and line (and the message), so one run lists every failure; main returns non-zero when
 * g_failures is. With lensrt.h included first: CHECK_RES (a call's result code against
 * the expected one, with the context's last error), CHECK_OK and CHECK_MSG. And
 * read_text, a whole file as a NUL-terminated string (malloc'd; NULL if unreadable);
 * stamp_table and load_stamped, a table edited by a test given its probe lines and
 * checksum line as lensfit would write them; stamp_crc, the checksum line only. */
#ifndef LENSRT_TEST_CHECK_H
#define LENSRT_TEST_CHECK_H

#include <math.h>
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

/* `text` with a checksum line (a bitwise CRC-32, independent of the library's
 * table-driven one) of all before it: an old checksum line (the last, or in the middle
 * after a test appended lines) becomes a comment, so that every line keeps its number,
 * and a final newline is added. Nothing else changes (the probe lines are not made
 * again: the probe tests use this). The malloc'd copy's size goes to *out_size (NULL on
 * failure). */
static inline char *stamp_crc(const char *text, size_t size, size_t *out_size)
{
    char *out = malloc(size + 32);
    size_t n = size, start, k;
    uint32_t crc = 0xFFFFFFFFu;
    *out_size = 0;
    if (!out) return NULL;
    memcpy(out, text, size);
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

/* The probe points of lensfit's writer (fit/lensfit/codegen/table.py, PROBE_XHAT):
 * normalised, one row per probe line, one column per input. */
#define STAMP_PROBES 6
static const double STAMP_XHAT[STAMP_PROBES][8] = {
    {0.5692, -0.7758, 0.4534, -0.9197, 0.3358, -0.6936, 0.8800, -0.5333},
    {-0.8173, 0.5504, -0.6690, 0.3538, -0.9620, 0.4623, -0.7562, 0.2821},
    {0.9427, -0.3267, 0.7205, -0.5770, 0.6536, -0.8773, 0.3718, -0.4821},
    {-0.4518, 0.9324, -0.3968, 0.7237, -0.5862, 0.8096, -0.6751, 0.5896},
    {0.9912, -0.9637, 0.9345, -0.9786, 0.9123, -0.9478, 0.9871, -0.9254},
    {-0.9561, 0.9058, -0.9893, 0.9402, -0.9734, 0.9217, -0.9049, 0.9688},
};

/* What stamp_table knows of the system it is in: its inputs' domains and transforms
 * and its outputs' terms so far. */
typedef struct stamp_system {
    int n_in, n_out, inputs, k, left;
    int inverse[8];
    double lo[8], hi[8], c[8], s[8];
    int n_terms[8], cap[8];
    unsigned char *e[8];
    double *coef[8];
} stamp_system;

static inline void stamp_reset(stamp_system *st)
{
    int k;
    for (k = 0; k < 8; k++) {
        free(st->e[k]);
        free(st->coef[k]);
    }
    memset(st, 0, sizeof *st);
}

/* The probe lines of the system st describes, as lensfit writes them (inputs from the
 * normalised points through c and s, outputs evaluated as lensrt's reader does, so that
 * they agree bit for bit), at o; the bytes written. */
static inline size_t stamp_probes(const stamp_system *st, char *o)
{
    size_t n = 0;
    int p, j, k, t, d;
    for (p = 0; p < STAMP_PROBES; p++) {
        double v[8], pw[8][16];
        n += (size_t)sprintf(o + n, "probe");
        for (j = 0; j < st->n_in; j++) {
            double w = st->c[j] + st->s[j] * STAMP_XHAT[p][j], x;
            v[j] = st->inverse[j] ? (w > 0 ? 1.0 / sqrt(w) : st->lo[j]) : w;
            if (v[j] < st->lo[j]) v[j] = st->lo[j];
            if (v[j] > st->hi[j]) v[j] = st->hi[j];
            x = ((st->inverse[j] ? 1.0 / (v[j] * v[j]) : v[j]) - st->c[j]) / st->s[j];
            pw[j][0] = 1.0;
            for (d = 1; d < 16; d++) pw[j][d] = pw[j][d - 1] * x;
            n += (size_t)sprintf(o + n, " %.17g", v[j]);
        }
        for (k = 0; k < st->n_out; k++) {
            double sum = 0.0;
            for (t = 0; t < st->n_terms[k]; t++) {
                double m = st->coef[k][t];
                for (j = 0; j < st->n_in; j++) m *= pw[j][st->e[k][t * st->n_in + j] & 15];
                sum += m;
            }
            n += (size_t)sprintf(o + n, " %.17g", sum);
        }
        o[n++] = '\n';
    }
    return n;
}

/* One line of a system (fields f[0..nf-1]) into st. */
static inline void stamp_line(stamp_system *st, char **f, int nf)
{
    int j;
    if (strcmp(f[0], "input") == 0 && nf == 8 && st->inputs < st->n_in) {
        j = st->inputs++;
        st->lo[j] = strtod(f[3], NULL);
        st->hi[j] = strtod(f[4], NULL);
        st->inverse[j] = strcmp(f[5], "inverse_square") == 0;
        st->c[j] = strtod(f[6], NULL);
        st->s[j] = strtod(f[7], NULL);
    } else if (strcmp(f[0], "output") == 0 && nf == 4 && st->k + 1 < st->n_out) {
        st->k++;
        st->left = atoi(f[3]);
    } else if (st->k >= 0 && st->left > 0 && nf == st->n_in + 1) {
        int k = st->k, t = st->n_terms[k];
        if (t == st->cap[k]) {
            int cap = st->cap[k] ? 2 * st->cap[k] : 64;
            unsigned char *e = realloc(st->e[k], (size_t)cap * (size_t)st->n_in);
            double *c = e ? realloc(st->coef[k], (size_t)cap * sizeof *c) : NULL;
            if (e) st->e[k] = e;
            if (!c) return;
            st->coef[k] = c;
            st->cap[k] = cap;
        }
        for (j = 0; j < st->n_in; j++) st->e[k][t * st->n_in + j] = (unsigned char)atoi(f[j]);
        st->coef[k][t] = strtod(f[st->n_in], NULL);
        st->n_terms[k]++;
        st->left--;
    }
}

/* A table text as lensfit would write it after a test's edit (version 5): a header of
 * version 3 or 4 made 5, each system's probe lines made again from its polynomials as
 * the text has them (old ones dropped, new ones before its `end`), then stamp_crc.
 * Tests that change a table to reach one of the parser's checks stamp it, as the
 * checksum and the probes would refuse it first. NULL on failure. */
static inline char *stamp_table(const char *text, size_t size, size_t *out_size)
{
    size_t cap = size + 64, n = 0, i = 0, ends = 0;
    char *out, *stamped, line[4096];
    stamp_system st;
    int in_system = 0, first = 1;
    *out_size = 0;
    for (i = 0; i + 4 <= size; i++)
        if ((i == 0 || text[i - 1] == '\n') && memcmp(text + i, "end", 3) == 0) ends++;
    cap += (ends + 1) * STAMP_PROBES * 480;
    if (!(out = malloc(cap))) return NULL;
    memset(&st, 0, sizeof st);
    for (i = 0; i < size;) {
        const char *eol = memchr(text + i, '\n', size - i);
        size_t len = eol ? (size_t)(eol - (text + i)) + 1 : size - i;
        char *f[24];
        int nf = 0;
        size_t m = len < sizeof line ? len : sizeof line - 1;
        char *q = line;
        memcpy(line, text + i, m);
        line[m] = '\0';
        while (nf < 24) {
            while (*q == ' ' || *q == '\t' || *q == '\n' || *q == '\r') *q++ = '\0';
            if (!*q) break;
            f[nf++] = q;
            while (*q && *q != ' ' && *q != '\t' && *q != '\n' && *q != '\r') q++;
        }
        if (first && nf == 2 && strcmp(f[0], "lensfit-poly-table") == 0 &&
            (strcmp(f[1], "3") == 0 || strcmp(f[1], "4") == 0)) {
            n += (size_t)sprintf(out + n, "lensfit-poly-table 5\n");
            first = 0;
            i += len;
            continue;
        }
        if (nf && f[0][0] != '#') first = 0;
        if (nf && strcmp(f[0], "system") == 0 && nf == 4) {
            stamp_reset(&st);
            st.n_in = atoi(f[2]);
            st.n_out = atoi(f[3]);
            st.k = -1;
            in_system = st.n_in >= 1 && st.n_in <= 8 && st.n_out >= 1 && st.n_out <= 8;
        } else if (in_system && nf && strcmp(f[0], "probe") == 0) {
            i += len; /* made again before `end` */
            continue;
        } else if (in_system && nf == 1 && strcmp(f[0], "end") == 0) {
            if (st.inputs == st.n_in) n += stamp_probes(&st, out + n);
            in_system = 0;
        } else if (in_system && nf) {
            stamp_line(&st, f, nf);
        }
        memcpy(out + n, text + i, len);
        n += len;
        i += len;
    }
    stamp_reset(&st);
    stamped = stamp_crc(out, n, out_size);
    free(out);
    return stamped;
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
