/* PSF banks: the `lensrt-bank` index reader.
 *
 * The reader is as strict as the coefficient table reader (lens/table.c): the checksum
 * line is checked first (core/crc32.h, the same line tables end with; io/bank.c), then
 * every line in its fixed order. Numbers are read in the "C" locale (c_numbers.h) and
 * characters classified as ASCII, whatever the host's locale. */
#include "../c_numbers.h"
#include "bank.h"

#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* The grids' keys, in the index's order after the wavelengths (AXIS_*). */
static const char *const AXIS_KEYS[N_AXES] = {"wavelengths_nm",   "f_numbers",   "focus_offsets_mm",
                                              "distances_mm",     "field_x_deg", "field_y_deg"};

/* --------------------------------------------------------------- the index ----- */

/* A cursor over the index's lines (a writable copy: lines and tokens are cut in place). */
typedef struct bank_reader {
    lensrt_context ctx;
    const char *file;   /* the index path, for messages */
    char *p, *end;      /* the rest of the body (everything before the checksum line) */
    int line;
    char *cursor;       /* the rest of the current line */
    const char *key;    /* its first token */
    int pending;        /* 1: the current line is read but not yet taken (an optional key's) */
} bank_reader;

static lensrt_result index_fail(bank_reader *r, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 2, 3)))
#endif
    ;
static lensrt_result index_fail(bank_reader *r, const char *fmt, ...)
{
    char msg[768];
    va_list args;
    va_start(args, fmt);
    lensrt_vsnprintf_c(msg, sizeof msg, fmt, args);
    va_end(args);
    return lensrt_fail(r->ctx, LENSRT_ERROR_PARSE, "bank index %s:%d: %s", r->file, r->line, msg);
}

/* The next line, checked for its form (printable ASCII, single spaces between tokens,
 * none at either end), its first token in r->key: 1, or 0 at the end of the body, or
 * -1 after recording what is wrong with it. */
static int next_line(bank_reader *r)
{
    char *eol, *start, *s;
    if (r->p >= r->end) return 0;
    // The body ends with the '\n' before the checksum line, so every line has its '\n'
    eol = memchr(r->p, '\n', (size_t)(r->end - r->p));
    if (!eol) eol = r->end;
    *eol = '\0';
    r->line++;
    start = r->p;
    r->p = eol + 1;
    if (start == eol) return index_fail(r, "a blank line (the index has none)"), -1;
    if (start[0] == ' ' || eol[-1] == ' ')
        return index_fail(r, "a space at the %s of the line (tokens are separated by single spaces)",
                          start[0] == ' ' ? "start" : "end"), -1;
    for (s = start; s < eol; s++) {
        unsigned char c = (unsigned char)*s;
        if (c == '\r') return index_fail(r, "a carriage return: lines end with LF alone"), -1;
        if (c < 0x20 || c > 0x7e)
            return index_fail(r, "byte 0x%02x at column %d: the index is printable ASCII", c, (int)(s - start) + 1), -1;
        if (c == ' ' && s[1] == ' ') return index_fail(r, "two spaces in a row (tokens are separated by one)"), -1;
    }
    r->cursor = start;
    return 1;
}

/* The next token of the current line, or NULL at its end. */
static char *next_token(bank_reader *r)
{
    char *t = r->cursor, *s;
    if (*t == '\0') return NULL;
    for (s = t; *s != '\0' && *s != ' '; s++) continue;
    if (*s == ' ') *s++ = '\0';
    r->cursor = s;
    return t;
}

/* The tokens left on the current line. */
static int tokens_left(const bank_reader *r)
{
    const char *s = r->cursor;
    int n = *s != '\0';
    for (; *s; s++) n += *s == ' ';
    return n;
}

/* Is key one of the index's? */
static int known_key(const char *key)
{
    static const char *const keys[] = {"lensrt-bank", "lens", "table_crc32", "width", "height", "pixel_mm", "registration",
                                       "wavelengths_nm", "f_numbers", "focus_offsets_mm", "distances_mm",
                                       "field_x_deg", "field_y_deg", "nodes", "node", "chief", "checksum"};
    size_t i;
    for (i = 0; i < sizeof keys / sizeof keys[0]; i++)
        if (strcmp(key, keys[i]) == 0) return 1;
    return 0;
}

/* The next line, which must start with `key` and hold `n_values` tokens after it (-1:
 * any number): its first value is next_token's. `what` says what the line holds. */
static lensrt_result expect_line(bank_reader *r, const char *key, int n_values, const char *what)
{
    int got = r->pending ? 1 : next_line(r), n;
    if (got < 0) return LENSRT_ERROR_PARSE;
    if (got == 0) {
        // The missing line would have been where the checksum line is
        r->line++;
        return index_fail(r, "the index ends before its '%s' line (%s); expected the keys in order: lensrt-bank, "
                             "lens, table_crc32, width, height, pixel_mm, wavelengths_nm, f_numbers, "
                             "focus_offsets_mm, distances_mm, field_x_deg, field_y_deg, nodes, then node and "
                             "chief lines", key, what);
    }
    if (!r->pending) r->key = next_token(r);
    r->pending = 0;
    if (strcmp(r->key, key) != 0) {
        if (known_key(r->key))
            return index_fail(r, "key '%.64s' is out of order or repeated: expected '%s' (%s) here", r->key, key,
                              what);
        return index_fail(r, "unknown key '%.64s': expected '%s' (%s)", r->key, key, what);
    }
    n = tokens_left(r);
    if (n_values >= 0 && n != n_values)
        return index_fail(r, "'%s' takes %d value%s (%s), found %d", key, n_values, n_values == 1 ? "" : "s", what,
                          n);
    return LENSRT_SUCCESS;
}

/* A decimal number: digits, sign, point and exponent only (no inf, nan or hex), all of the
 * token read, finite. */
int lensrt_bank_parse_number(const char *s, double *v)
{
    const char *c;
    char *end;
    for (c = s; *c; c++)
        if (!((*c >= '0' && *c <= '9') || *c == '.' || *c == '-' || *c == '+' || *c == 'e' || *c == 'E')) return 0;
    errno = 0;
    *v = lensrt_strtod_c(s, &end);
    return end != s && *end == '\0' && isfinite(*v);
}

/* A decimal integer in [lo, hi]: ASCII digits with an optional '-', nothing else. */
int lensrt_bank_parse_integer(const char *s, long lo, long hi, long *v)
{
    long x = 0;
    int negative = *s == '-';
    if (negative) s++;
    if (*s == '\0') return 0;
    for (; *s; s++) {
        if (*s < '0' || *s > '9') return 0;
        x = 10 * x + (*s - '0');
        if (x > 2147483647L) return 0; /* beyond any bound: stop before overflow */
    }
    *v = negative ? -x : x;
    return *v >= lo && *v <= hi;
}

/* 8 lowercase hex digits. */
static int parse_crc(const char *s, uint32_t *v)
{
    int k;
    *v = 0;
    if (strlen(s) != 8) return 0;
    for (k = 0; k < 8; k++) {
        char c = s[k];
        if (!((c >= '0' && c <= '9') || (c >= 'a' && c <= 'f'))) return 0;
        *v = *v << 4 | (uint32_t)(c <= '9' ? c - '0' : c - 'a' + 10);
    }
    return 1;
}

/* The next token as a number for `key` (its value `index`, 1-based, in messages). */
static lensrt_result read_number(bank_reader *r, const char *key, int index, double *v)
{
    const char *t = next_token(r);
    if (!t) return index_fail(r, "'%s': value %d is missing", key, index);
    if (!lensrt_bank_parse_number(t, v)) return index_fail(r, "'%s': value %d '%.64s' is not a finite decimal number", key, index, t);
    return LENSRT_SUCCESS;
}

/* The next token as an integer in [lo, hi] for `key`. */
static lensrt_result read_integer(bank_reader *r, const char *key, const char *what, long lo, long hi, long *v)
{
    const char *t = next_token(r);
    if (!t) return index_fail(r, "'%s': the %s is missing", key, what);
    if (!lensrt_bank_parse_integer(t, lo, hi, v))
        return index_fail(r, "'%s': the %s '%.64s' is not an integer in [%ld, %ld]", key, what, t, lo, hi);
    return LENSRT_SUCCESS;
}

static int compare_doubles(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : x > y ? 1 : 0;
}

/* One of the six grids: `<key> <n> <v_1> ... <v_n>`, each value checked for its axis. */
static lensrt_result read_axis(bank_reader *r, lensrt_bank b, int axis)
{
    const char *key = AXIS_KEYS[axis];
    const long max = axis == AXIS_WAVELENGTH ? LENSRT_MAX_WAVELENGTHS : LENSRT_MAX_BANK_NODES;
    double *v, *sorted;
    long n;
    int i;
    lensrt_result res;
    if ((res = expect_line(r, key, -1, "a count, then the values")) != LENSRT_SUCCESS) return res;
    if ((res = read_integer(r, key, "count", 1, max, &n)) != LENSRT_SUCCESS) return res;
    if (tokens_left(r) != n)
        return index_fail(r, "'%s' says %ld value%s and gives %d", key, n, n == 1 ? "" : "s", tokens_left(r));
    v = b->values[axis] = lensrt_alloc(b->ctx, (size_t)n * sizeof(double));
    if (!v) return lensrt_fail(b->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "bank index %s: out of memory", r->file);
    b->n[axis] = (int)n;
    for (i = 0; i < n; i++) {
        if ((res = read_number(r, key, i + 1, &v[i])) != LENSRT_SUCCESS) return res;
        // Each axis's range
        if (axis == AXIS_WAVELENGTH && !(v[i] > 0.0 && v[i] < LENSRT_EXR_MAX_WAVELENGTH_NM))
            return index_fail(r, "'%s': value %d is %.17g nm; wavelengths are > 0 and < %g nm", key, i + 1, v[i],
                              LENSRT_EXR_MAX_WAVELENGTH_NM);
        if (axis == AXIS_F && !(v[i] > 0.0))
            return index_fail(r, "'%s': value %d is %.17g; f-numbers are > 0", key, i + 1, v[i]);
        if (axis == AXIS_DISTANCE && !(v[i] >= 0.0))
            return index_fail(r, "'%s': value %d is %.17g mm; distances are >= 0 (0: infinity)", key, i + 1, v[i]);
        if ((axis == AXIS_FIELD_X || axis == AXIS_FIELD_Y) && !(fabs(v[i]) < 90.0))
            return index_fail(r, "'%s': value %d is %.17g deg; field angles are within (-90, 90)", key, i + 1, v[i]);
        // The field and wavelength grids are interpolated: strictly increasing
        if ((axis == AXIS_WAVELENGTH || axis == AXIS_FIELD_X || axis == AXIS_FIELD_Y) && i > 0 && !(v[i] > v[i - 1]))
            return index_fail(r, "'%s': value %d (%.17g) does not exceed value %d (%.17g); the values are strictly "
                                 "increasing", key, i + 1, v[i], i, v[i - 1]);
    }
    // Wavelengths distinct as channel names (6 decimals); the others distinct (a sorted copy)
    if (axis == AXIS_WAVELENGTH) {
        char a[LENSRT_EXR_SPECTRAL_NAME_SIZE], c[LENSRT_EXR_SPECTRAL_NAME_SIZE];
        for (i = 1; i < n; i++) {
            lensrt_exr_spectral_name(v[i - 1], a);
            lensrt_exr_spectral_name(v[i], c);
            if (strcmp(a, c) == 0)
                return index_fail(r, "'%s': values %d and %d (%.17g and %.17g nm) give the same EXR channel '%s'",
                                  key, i, i + 1, v[i - 1], v[i], a);
        }
    } else if (axis == AXIS_F || axis == AXIS_FOCUS || axis == AXIS_DISTANCE) {
        sorted = lensrt_alloc(b->ctx, (size_t)n * sizeof(double));
        if (!sorted) return lensrt_fail(b->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "bank index %s: out of memory", r->file);
        memcpy(sorted, v, (size_t)n * sizeof(double));
        qsort(sorted, (size_t)n, sizeof(double), compare_doubles);
        for (i = 1; i < n && sorted[i] != sorted[i - 1]; i++) continue;
        if (i < n) {
            double twice = sorted[i];
            lensrt_free(b->ctx, sorted);
            return index_fail(r, "'%s': the value %.17g appears twice; the values are distinct", key, twice);
        }
        lensrt_free(b->ctx, sorted);
    }
    return LENSRT_SUCCESS;
}

/* NULL when `path` may name a node's EXR (relative, [A-Za-z0-9._/-] only, no empty, '.'
 * or '..' component), else why not. */
static const char *path_refusal(const char *path)
{
    const char *s, *part;
    if (!path[0]) return "is empty";
    if (strlen(path) >= BANK_PATH_SIZE) return "is too long";
    if (path[0] == '/') return "starts with '/' (paths are relative to the index's folder)";
    for (s = path; *s; s++)
        if (!((*s >= 'A' && *s <= 'Z') || (*s >= 'a' && *s <= 'z') || (*s >= '0' && *s <= '9') || *s == '.' ||
              *s == '_' || *s == '/' || *s == '-'))
            return "has a character other than A-Z, a-z, 0-9, '.', '_', '/' and '-'";
    if (strstr(path, "..")) return "holds '..' (a node lies inside the bank's folder)";
    // Components: none empty ('//', a final '/') or '.'
    for (part = path; *part; part = *s ? s + 1 : s) {
        for (s = part; *s && *s != '/'; s++) continue;
        if (s == part) return "has an empty component ('//' or a final '/')";
        if (s - part == 1 && part[0] == '.') return "has a '.' component";
        if (*s == '/' && s[1] == '\0') return "ends with '/'";
    }
    return NULL;
}

/* The nodes: `nodes N`, then a node line and a chief line for each k. */
static lensrt_result read_nodes(bank_reader *r, lensrt_bank b)
{
    const int nw = b->n[AXIS_WAVELENGTH];
    const int dims[5] = {b->n[AXIS_F], b->n[AXIS_FOCUS], b->n[AXIS_DISTANCE], b->n[AXIS_FIELD_Y], b->n[AXIS_FIELD_X]};
    static const char *const index_names[5] = {"i_f", "i_z", "i_d", "i_y", "i_x"};
    long n, product = 1, k, v;
    int *line_of; /* the line of the node holding each tuple (0: none yet) */
    lensrt_result res;
    int a, w;
    // The grid's node count, saturated past the limit (five counts of up to 65536 each)
    for (a = 0; a < 5; a++) product = product > LENSRT_MAX_BANK_NODES ? product : product * dims[a];
    if ((res = expect_line(r, "nodes", 1, "the number of nodes")) != LENSRT_SUCCESS) return res;
    if ((res = read_integer(r, "nodes", "count", 1, LENSRT_MAX_BANK_NODES, &n)) != LENSRT_SUCCESS) return res;
    if (product > LENSRT_MAX_BANK_NODES)
        return index_fail(r, "the grid has %d x %d x %d x %d x %d nodes (f-numbers x focus offsets x distances x "
                             "field_y x field_x), more than LENSRT_MAX_BANK_NODES (%d)", dims[0], dims[1], dims[2],
                          dims[3], dims[4], LENSRT_MAX_BANK_NODES);
    if (n != product)
        return index_fail(r, "'nodes %ld': expected %d x %d x %d x %d x %d = %ld (f-numbers x focus offsets x "
                             "distances x field_y x field_x), one node each", n, dims[0], dims[1], dims[2], dims[3],
                          dims[4], product);
    b->nodes = lensrt_calloc(b->ctx, (size_t)n, sizeof(bank_node));
    line_of = lensrt_calloc(b->ctx, (size_t)n, sizeof(int));
    if (!b->nodes || !line_of) {
        lensrt_free(b->ctx, line_of);
        return lensrt_fail(b->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "bank index %s: out of memory", r->file);
    }
    b->n_nodes = (int)n;
    res = LENSRT_SUCCESS;
    for (k = 0; k < n && res == LENSRT_SUCCESS; k++) {
        long tuple[5], slot = 0;
        bank_node *node;
        const char *t, *refusal;
        double cx, cy, err;
        uint32_t crc;
        int line;
        // The node line: its place, its indices, centre, estimate, CRC and path
        if ((res = expect_line(r, "node", 11, "k i_f i_z i_d i_y i_x center_x_mm center_y_mm error_estimate crc32 "
                                              "path")) != LENSRT_SUCCESS) break;
        if ((res = read_integer(r, "node", "number k", k, k, &v)) != LENSRT_SUCCESS) break;
        for (a = 0; a < 5 && res == LENSRT_SUCCESS; a++) {
            res = read_integer(r, "node", index_names[a], 0, dims[a] - 1, &tuple[a]);
            slot = slot * dims[a] + tuple[a];
        }
        if (res != LENSRT_SUCCESS) break;
        if (line_of[slot]) {
            res = index_fail(r, "node %ld has the indices (%ld, %ld, %ld, %ld, %ld) of the node at line %d; each "
                                "appears once", k, tuple[0], tuple[1], tuple[2], tuple[3], tuple[4], line_of[slot]);
            break;
        }
        line_of[slot] = line = r->line;
        if ((res = read_number(r, "node", 7, &cx)) != LENSRT_SUCCESS) break;
        if ((res = read_number(r, "node", 8, &cy)) != LENSRT_SUCCESS) break;
        if ((res = read_number(r, "node", 9, &err)) != LENSRT_SUCCESS) break;
        if (!(err >= 0.0 || err == -1.0)) {
            res = index_fail(r, "node %ld: error_estimate %.17g is negative (-1 alone says there is none)", k, err);
            break;
        }
        t = next_token(r);
        if (!parse_crc(t, &crc)) {
            res = index_fail(r, "node %ld: crc32 '%.64s' is not 8 lowercase hex digits", k, t);
            break;
        }
        t = next_token(r);
        if ((refusal = path_refusal(t)) != NULL) {
            res = index_fail(r, "node %ld: path '%.200s' %s", k, t, refusal);
            break;
        }
        node = &b->nodes[slot];
        memcpy(node->tuple, tuple, sizeof tuple);
        node->k = (int)k;
        node->line = line;
        node->center_x = cx;
        node->center_y = cy;
        node->error_estimate = err;
        node->crc = crc;
        if (!(node->path = lensrt_alloc(b->ctx, strlen(t) + 1))) {
            res = lensrt_fail(b->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "bank index %s: out of memory", r->file);
            break;
        }
        memcpy(node->path, t, strlen(t) + 1);
        // The worst estimate: unknown (-1) once a node has none
        if (err < 0.0) b->worst_error = -1.0;
        else if (b->worst_error >= 0.0 && err > b->worst_error) b->worst_error = err;
        // The chief line: the chief ray's image point at each wavelength, inside the node's
        // image when the node is registered on it
        if ((res = expect_line(r, "chief", 1 + 2 * nw, "k, then x y (mm) at each wavelength")) != LENSRT_SUCCESS) break;
        if ((res = read_integer(r, "chief", "number k", k, k, &v)) != LENSRT_SUCCESS) break;
        node->chief = lensrt_alloc(b->ctx, 2 * (size_t)nw * sizeof(double));
        if (!node->chief) {
            res = lensrt_fail(b->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "bank index %s: out of memory", r->file);
            break;
        }
        for (w = 0; w < 2 * nw && res == LENSRT_SUCCESS; w++) res = read_number(r, "chief", w + 2, &node->chief[w]);
        for (w = 0; w < nw && res == LENSRT_SUCCESS && b->registration == REGISTRATION_CHIEF; w++) {
            const double hx = 0.5 * b->width * b->pixel_x, hy = 0.5 * b->height * b->pixel_y;
            const double ux = node->chief[2 * w], uy = node->chief[2 * w + 1];
            if (!(fabs(ux - cx) <= hx && fabs(uy - cy) <= hy))
                res = index_fail(r, "node %ld: the chief point (%.17g, %.17g) mm at %.17g nm lies outside the node's "
                                    "image, [%.17g, %.17g] x [%.17g, %.17g] mm", k, ux, uy, b->values[AXIS_WAVELENGTH][w],
                                 cx - hx, cx + hx, cy - hy, cy + hy);
        }
    }
    lensrt_free(b->ctx, line_of);
    if (res != LENSRT_SUCCESS) return res;
    // Nothing but the checksum line after the last node
    if ((w = next_line(r)) != 0)
        return w < 0 ? LENSRT_ERROR_PARSE
                     : index_fail(r, "'%.64s' after the last node (%d nodes): only the checksum line follows",
                                  next_token(r), b->n_nodes);
    return LENSRT_SUCCESS;
}

/* Parse the index's body (checked against its checksum line already). */
static lensrt_result read_index(bank_reader *r, lensrt_bank b)
{
    lensrt_result res;
    const char *t;
    long v;
    double x;
    int axis;
    // The header: the format and its version
    if ((res = expect_line(r, "lensrt-bank", 1, "the format's version")) != LENSRT_SUCCESS) return res;
    if ((res = read_integer(r, "lensrt-bank", "version", 1, 1000000, &v)) != LENSRT_SUCCESS) return res;
    if (v != 1) return index_fail(r, "version %ld: this lensrt reads version 1 of the bank index", v);
    // The lens: its name and its table's checksum
    if ((res = expect_line(r, "lens", 1, "the lens's name")) != LENSRT_SUCCESS) return res;
    t = next_token(r);
    if (strlen(t) >= sizeof b->lens_name) return index_fail(r, "'lens': the name is longer than %d characters",
                                                            (int)sizeof b->lens_name - 1);
    snprintf(b->lens_name, sizeof b->lens_name, "%s", t);
    if ((res = expect_line(r, "table_crc32", 1, "the lens table's checksum")) != LENSRT_SUCCESS) return res;
    t = next_token(r);
    if (!parse_crc(t, &b->table_crc32)) return index_fail(r, "'table_crc32': '%.64s' is not 8 lowercase hex digits", t);
    // The node images' size and pitch
    if ((res = expect_line(r, "width", 1, "pixels of each node image")) != LENSRT_SUCCESS) return res;
    if ((res = read_integer(r, "width", "value", 1, LENSRT_MAX_RESOLUTION, &v)) != LENSRT_SUCCESS) return res;
    b->width = (int)v;
    if ((res = expect_line(r, "height", 1, "pixels of each node image")) != LENSRT_SUCCESS) return res;
    if ((res = read_integer(r, "height", "value", 1, LENSRT_MAX_RESOLUTION, &v)) != LENSRT_SUCCESS) return res;
    b->height = (int)v;
    if ((res = expect_line(r, "pixel_mm", 2, "the pixel pitch in x and y")) != LENSRT_SUCCESS) return res;
    if ((res = read_number(r, "pixel_mm", 1, &b->pixel_x)) != LENSRT_SUCCESS) return res;
    if ((res = read_number(r, "pixel_mm", 2, &x)) != LENSRT_SUCCESS) return res;
    b->pixel_y = x;
    if (!(b->pixel_x > 0.0 && b->pixel_y > 0.0))
        return index_fail(r, "'pixel_mm %.17g %.17g': the pitch is > 0", b->pixel_x, b->pixel_y);
    // Optional: how the nodes are registered (chief, the default, or one shared window)
    if ((v = next_line(r)) < 0) return LENSRT_ERROR_PARSE;
    r->pending = (int)v;
    if (v && strcmp(r->key = next_token(r), "registration") == 0) {
        r->pending = 0;
        t = next_token(r);
        for (v = 0; v < 3 && t && strcmp(t, REGISTRATION_NAMES[v]) != 0; v++) continue;
        if (!t || tokens_left(r) != 0 || v == 3)
            return index_fail(r, "'registration' takes 'chief', 'window' or 'channel', found '%.64s%s'", t ? t : "",
                              t && tokens_left(r) ? " ..." : "");
        b->registration = (int)v;
    }
    // The grids, then the nodes
    for (axis = 0; axis < N_AXES; axis++)
        if ((res = read_axis(r, b, axis)) != LENSRT_SUCCESS) return res;
    if ((size_t)b->width * (size_t)b->height * (size_t)b->n[AXIS_WAVELENGTH] > BANK_MAX_NODE_FLOATS)
        return index_fail(r, "%d x %d pixels at %d wavelengths is more than %zu values per node", b->width, b->height,
                          b->n[AXIS_WAVELENGTH], BANK_MAX_NODE_FLOATS);
    return read_nodes(r, b);
}

lensrt_result lensrt_bank_read_index(lensrt_bank b, char *body, char *end)
{
    bank_reader r;
    memset(&r, 0, sizeof r);
    r.ctx = b->ctx;
    r.file = b->index_path;
    r.p = body;
    r.end = end;
    return read_index(&r, b);
}
