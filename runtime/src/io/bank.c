/* PSF banks (lensrt.h, "PSF banks"): the `lensrt-bank` index reader, the node images
 * read through OpenEXRCore, and the PSF at a field point and wavelength blended from
 * the nodes around it.
 *
 * The reader is as strict as the coefficient table reader (lens/table.c): the checksum
 * line is checked first (core/crc32.h, the same line tables end with), then every line
 * in its fixed order, then every node's EXR against its CRC-32 in the index, its size,
 * its channels and its values. Everything is read from memory: the index and each EXR
 * are read whole, checked, then parsed (OpenEXRCore reads the EXR from our buffer, so
 * the bytes decoded are the bytes whose CRC was checked). Numbers are read in the "C"
 * locale (c_numbers.h) and characters classified as ASCII, whatever the host's locale.
 *
 * Resampling. The output has the bank's pitch, so registering a node's channel on its
 * chief point shifts the whole node image by one constant vector: with the node centred
 * on (cx, cy) and the channel's chief point at (ux, uy), output pixel (i, j) reads the
 * node at fractional pixel (i + dx, j + dy), dx = (ux - cx) / pitch_x and
 * dy = -(uy - cy) / pitch_y (row 0 is +y). So each (node, channel) term is four taps with
 * the same bilinear weights for every pixel, and a term whose shift is zero copies the
 * channel exactly. */
#include "../c_numbers.h"
#include "../core/crc32.h"
#include "../internal.h"
#include "image_io.h"

#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#ifdef LENSRT_EXR
#include <OpenEXR/openexr.h>
#endif

/* How node images are placed (the index's `registration`): chief, each node's window on
 * its middle chief point (channels shifted on read); window, one window shared by every
 * node (blended in place); channel, each channel's window on its own chief point (read
 * with no shift at all: a node's channel is the PSF bit for bit). */
enum { REGISTRATION_CHIEF = 0, REGISTRATION_WINDOW, REGISTRATION_CHANNEL };
static const char *const REGISTRATION_NAMES[] = {"chief", "window", "channel"};

/* The grids of a bank, in the index's order after the wavelengths. */
enum { AXIS_WAVELENGTH = 0, AXIS_F, AXIS_FOCUS, AXIS_DISTANCE, AXIS_FIELD_X, AXIS_FIELD_Y, N_AXES };
static const char *const AXIS_KEYS[N_AXES] = {"wavelengths_nm",   "f_numbers",   "focus_offsets_mm",
                                              "distances_mm",     "field_x_deg", "field_y_deg"};

/* Largest float count of one node image (1 GiB), and bytes of an index or node file. */
#define BANK_MAX_NODE_FLOATS ((size_t)1 << 28)
#define BANK_MAX_FILE_BYTES ((long)1 << 30)
/* Room for a lens name and a path (bytes, with the NUL). */
#define BANK_NAME_SIZE 256
#define BANK_PATH_SIZE 1024

typedef struct bank_node {
    int k;              /* its place in the index */
    int line;           /* its node line, for messages */
    double center_x, center_y, error_estimate;
    uint32_t crc;
    char *path;         /* relative to the index's folder (its own allocation: a bank of
                           LENSRT_MAX_BANK_NODES nodes holds 65,536 of them) */
    long tuple[5];      /* its indices (i_f, i_z, i_d, i_y, i_x) */
    double *chief;      /* x, y per wavelength (mm) */
    float *image;       /* n_wavelengths planes of width x height, row 0 at the top; NULL
                           until the node is first used (read_node) */
} bank_node;

struct lensrt_bank_s {
    lensrt_context ctx;
    char index_path[BANK_PATH_SIZE];
    char folder[BANK_PATH_SIZE]; /* the index's folder with its '/', or "" */
    char lens_name[BANK_NAME_SIZE];
    uint32_t table_crc32;
    int width, height;
    double pixel_x, pixel_y;
    int n[N_AXES];
    double *values[N_AXES];
    int n_nodes;
    bank_node *nodes;   /* by their index tuple: ((((f * nz + z) * nd + d) * ny + y) * nx + x) */
    int registration;   /* REGISTRATION_* below */
    double worst_error;
};

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
static int parse_number(const char *s, double *v)
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
static int parse_integer(const char *s, long lo, long hi, long *v)
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
    if (!parse_number(t, v)) return index_fail(r, "'%s': value %d '%.64s' is not a finite decimal number", key, index, t);
    return LENSRT_SUCCESS;
}

/* The next token as an integer in [lo, hi] for `key`. */
static lensrt_result read_integer(bank_reader *r, const char *key, const char *what, long lo, long hi, long *v)
{
    const char *t = next_token(r);
    if (!t) return index_fail(r, "'%s': the %s is missing", key, what);
    if (!parse_integer(t, lo, hi, v))
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

/* ------------------------------------------------------------------ files ----- */

/* A whole regular file into memory (the context's allocator); `what` names it in messages. */
static lensrt_result read_whole(lensrt_context ctx, const char *path, const char *what, unsigned char **out,
                                size_t *size)
{
    struct stat st;
    FILE *f;
    long n;
    *out = NULL;
    *size = 0;
    // A regular file only, checked before opening (a FIFO would block the open)
    if (stat(path, &st) != 0) return lensrt_fail(ctx, LENSRT_ERROR_IO, "%s: cannot open %s: %s", path, what, strerror(errno));
    if (!S_ISREG(st.st_mode)) return lensrt_fail(ctx, LENSRT_ERROR_IO, "%s: not a regular file (%s)", path, what);
    if (!(f = fopen(path, "rb"))) return lensrt_fail(ctx, LENSRT_ERROR_IO, "%s: cannot open %s: %s", path, what, strerror(errno));
    if (fseek(f, 0, SEEK_END) != 0 || (n = ftell(f)) < 0 || fseek(f, 0, SEEK_SET) != 0) {
        fclose(f);
        return lensrt_fail(ctx, LENSRT_ERROR_IO, "%s: cannot read %s", path, what);
    }
    if (n > BANK_MAX_FILE_BYTES) {
        fclose(f);
        return lensrt_fail(ctx, LENSRT_ERROR_IO, "%s: %ld bytes is more than a %s may hold (%ld)", path, n, what,
                           BANK_MAX_FILE_BYTES);
    }
    // One byte more, for a terminating NUL
    if (!(*out = lensrt_alloc(ctx, (size_t)n + 1))) {
        fclose(f);
        return lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_MEMORY, "%s: out of memory", path);
    }
    if (fread(*out, 1, (size_t)n, f) != (size_t)n) {
        fclose(f);
        lensrt_free(ctx, *out);
        *out = NULL;
        return lensrt_fail(ctx, LENSRT_ERROR_IO, "%s: short read of %s", path, what);
    }
    fclose(f);
    (*out)[n] = '\0';
    *size = (size_t)n;
    return LENSRT_SUCCESS;
}

#ifdef LENSRT_EXR

/* The EXR's bytes, which OpenEXRCore reads through read_memory and size_memory. */
typedef struct exr_memory {
    const unsigned char *data;
    size_t size;
} exr_memory;

static int64_t read_memory(exr_const_context_t ctxt, void *userdata, void *buffer, uint64_t sz, uint64_t offset,
                           exr_stream_error_func_ptr_t error_cb)
{
    const exr_memory *m = userdata;
    uint64_t n;
    (void)ctxt;
    (void)error_cb;
    // As pread: what there is from offset, 0 past the end
    if (offset >= m->size) return 0;
    n = m->size - offset < sz ? m->size - offset : sz;
    memcpy(buffer, m->data + offset, (size_t)n);
    return (int64_t)n;
}

static int64_t size_memory(exr_const_context_t ctxt, void *userdata)
{
    (void)ctxt;
    return (int64_t)((const exr_memory *)userdata)->size;
}

/* OpenEXRCore's own messages would go to stderr; ours name the file and the step. */
static void exr_quiet(exr_const_context_t ctxt, exr_result_t code, const char *msg)
{
    (void)ctxt;
    (void)code;
    (void)msg;
}

/* The node's identity in its EXR (attribute "lensrt/bankNode", written by lensfit's bank
 * nodes): "<i_f> <i_z> <i_d> <i_y> <i_x> <f_number> <focus_offset_mm> <distance_mm>
 * <field_x_deg> <field_y_deg>" (distance 0: infinity), equal to the index's. */
static lensrt_result check_identity(lensrt_bank b, const bank_node *node, const char *path, exr_context_t ctxt)
{
    // The values in the attribute's order, and which index of the tuple picks each
    const int value_axis[5] = {AXIS_F, AXIS_FOCUS, AXIS_DISTANCE, AXIS_FIELD_X, AXIS_FIELD_Y};
    const int value_slot[5] = {0, 1, 2, 4, 3};
    const char *text = NULL;
    char buf[512], *tok, *save = NULL;
    int32_t len = 0;
    long v;
    double x;
    int i, ok = 1;
    if (exr_attr_get_string(ctxt, 0, "lensrt/bankNode", &len, &text) != EXR_ERR_SUCCESS || !text)
        return lensrt_fail(b->ctx, LENSRT_ERROR_PARSE,
                           "%s: node %d (bank index %s:%d): no string attribute 'lensrt/bankNode' (which node the "
                           "image is); a `registration channel` bank's nodes carry it", path, node->k, b->index_path,
                           node->line);
    snprintf(buf, sizeof buf, "%.*s", len > 0 && len < (int32_t)sizeof buf ? (int)len : (int)sizeof buf - 1, text);
    tok = strtok_r(buf, " ", &save);
    for (i = 0; i < 5 && ok; i++, tok = strtok_r(NULL, " ", &save))
        ok = tok && parse_integer(tok, 0, LENSRT_MAX_BANK_NODES, &v) && v == node->tuple[i];
    for (i = 0; i < 5 && ok; i++, tok = strtok_r(NULL, " ", &save))
        ok = tok && parse_number(tok, &x) && x == b->values[value_axis[i]][node->tuple[value_slot[i]]];
    if (!ok || tok)
        return lensrt_fail(b->ctx, LENSRT_ERROR_PARSE,
                           "%s: node %d (bank index %s:%d): the image says it is node '%.200s' (lensrt/bankNode), not "
                           "this one (indices %ld %ld %ld %ld %ld): an EXR of another node or bank; refused", path,
                           node->k, b->index_path, node->line, text, node->tuple[0], node->tuple[1], node->tuple[2],
                           node->tuple[3], node->tuple[4]);
    return LENSRT_SUCCESS;
}

/* Decode node's EXR (bytes already checked against its CRC) into node->image: one
 * scanline part of width x height FLOAT pixels from (0, 0), exactly the index's spectral
 * channels plus R, G, B, every value finite and >= 0. */
static lensrt_result decode_node(lensrt_bank b, bank_node *node, const char *path, const unsigned char *bytes,
                                 size_t size)
{
    const int nw = b->n[AXIS_WAVELENGTH], w = b->width, h = b->height;
    const size_t plane = (size_t)w * (size_t)h;
    exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
    exr_context_t ctxt = NULL;
    exr_decode_pipeline_t decoder;
    exr_memory mem;
    const exr_attr_chlist_t *chlist = NULL;
    exr_attr_box2i_t dw;
    exr_storage_t storage;
    char (*names)[LENSRT_EXR_SPECTRAL_NAME_SIZE] = NULL;
    int *seen = NULL, parts = 0, decoder_live = 0, c, i, y;
    int32_t lines = 0;
    const char *step = "";
    exr_result_t rv;
    lensrt_result res = LENSRT_SUCCESS;
    size_t p;

    names = lensrt_alloc(b->ctx, (size_t)nw * sizeof *names);
    seen = lensrt_calloc(b->ctx, (size_t)nw, sizeof(int));
    node->image = lensrt_calloc(b->ctx, plane * (size_t)nw, sizeof(float));
    if (!names || !seen || !node->image) {
        res = lensrt_fail(b->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "%s: out of memory for node %d's image", path, node->k);
        goto done;
    }
    for (i = 0; i < nw; i++) lensrt_exr_spectral_name(b->values[AXIS_WAVELENGTH][i], names[i]);
    // Open the EXR from memory
    mem.data = bytes;
    mem.size = size;
    init.error_handler_fn = &exr_quiet;
    init.user_data = &mem;
    init.read_fn = &read_memory;
    init.size_fn = &size_memory;
    step = "reading the header";
    if ((rv = exr_start_read(&ctxt, path, &init)) != EXR_ERR_SUCCESS) goto exr_failed;
    // One scanline part of the index's size, from (0, 0)
    step = "reading the parts";
    if ((rv = exr_get_count(ctxt, &parts)) != EXR_ERR_SUCCESS) goto exr_failed;
    if ((rv = exr_get_storage(ctxt, 0, &storage)) != EXR_ERR_SUCCESS) goto exr_failed;
    if (parts != 1 || storage != EXR_STORAGE_SCANLINE) {
        res = lensrt_fail(b->ctx, LENSRT_ERROR_PARSE, "%s: node %d (bank index %s:%d): %d part%s%s; a node is one "
                                                      "scanline image", path, node->k, b->index_path, node->line, parts,
                          parts == 1 ? "" : "s", storage != EXR_STORAGE_SCANLINE ? ", not scanlines" : "");
        goto done;
    }
    step = "reading the data window";
    if ((rv = exr_get_data_window(ctxt, 0, &dw)) != EXR_ERR_SUCCESS) goto exr_failed;
    if (dw.min.x != 0 || dw.min.y != 0 || (int64_t)dw.max.x + 1 != w || (int64_t)dw.max.y + 1 != h) {
        res = lensrt_fail(b->ctx, LENSRT_ERROR_PARSE,
                          "%s: node %d (bank index %s:%d): the image is %lld x %lld pixels from (%d, %d); the index "
                          "says %d x %d from (0, 0)", path, node->k, b->index_path, node->line,
                          (long long)dw.max.x - dw.min.x + 1, (long long)dw.max.y - dw.min.y + 1, dw.min.x, dw.min.y, w,
                          h);
        goto done;
    }
    // A node of a `registration channel` bank says which node it is: its index tuple and
    // coordinates must be the index's (an EXR of another node, with the CRC in the index
    // updated to match, is refused)
    if (b->registration == REGISTRATION_CHANNEL && (res = check_identity(b, node, path, ctxt)) != LENSRT_SUCCESS)
        goto done;
    // The channels: each of the index's wavelengths once, FLOAT, full resolution; R, G, B ignored
    step = "reading the channels";
    if ((rv = exr_get_channels(ctxt, 0, &chlist)) != EXR_ERR_SUCCESS) goto exr_failed;
    for (c = 0; c < chlist->num_channels; c++) {
        const exr_attr_chlist_entry_t *e = &chlist->entries[c];
        const char *name = e->name.str;
        const char *dot = strchr(name, '.');
        char layer[LENSRT_MAX_LAYER_NAME + 2];
        if (strcmp(name, "R") == 0 || strcmp(name, "G") == 0 || strcmp(name, "B") == 0) continue;
        // A layer's channels ("direct.S0.550,000000nm", lensrt_layers_write_exr) are left to
        // other readers: the unprefixed ones hold the image, the layers' sum
        if (dot && dot - name <= LENSRT_MAX_LAYER_NAME) {
            snprintf(layer, sizeof layer, "%.*s", (int)(dot - name), name);
            if (!lensrt_exr_layer_name_refusal(layer)) continue;
        }
        for (i = 0; i < nw && strcmp(name, names[i]) != 0; i++) continue;
        if (i == nw) {
            res = lensrt_fail(b->ctx, LENSRT_ERROR_PARSE,
                              "%s: node %d (bank index %s:%d): channel '%.64s' is none of the index's wavelengths (%s "
                              "... %s) nor R, G, B", path, node->k, b->index_path, node->line, name, names[0],
                              names[nw - 1]);
            goto done;
        }
        if (e->pixel_type != EXR_PIXEL_FLOAT || e->x_sampling != 1 || e->y_sampling != 1) {
            res = lensrt_fail(b->ctx, LENSRT_ERROR_PARSE,
                              "%s: node %d (bank index %s:%d): channel '%s' is %s%s; node channels are FLOAT at every "
                              "pixel", path, node->k, b->index_path, node->line, name,
                              e->pixel_type == EXR_PIXEL_HALF ? "HALF" : e->pixel_type == EXR_PIXEL_UINT ? "UINT" : "FLOAT",
                              e->x_sampling != 1 || e->y_sampling != 1 ? ", subsampled" : "");
            goto done;
        }
        seen[i] = 1;
    }
    for (i = 0; i < nw; i++)
        if (!seen[i]) {
            res = lensrt_fail(b->ctx, LENSRT_ERROR_PARSE,
                              "%s: node %d (bank index %s:%d): no channel '%s' (the index's wavelength %.17g nm)", path,
                              node->k, b->index_path, node->line, names[i], b->values[AXIS_WAVELENGTH][i]);
            goto done;
        }
    // Decode every chunk, the spectral channels into their planes
    step = "decoding the pixels";
    if ((rv = exr_get_scanlines_per_chunk(ctxt, 0, &lines)) != EXR_ERR_SUCCESS) goto exr_failed;
    if (lines < 1) {
        rv = EXR_ERR_CORRUPT_CHUNK;
        goto exr_failed;
    }
    for (y = 0; y < h; y += lines) {
        exr_chunk_info_t chunk;
        if ((rv = exr_read_scanline_chunk_info(ctxt, 0, y, &chunk)) != EXR_ERR_SUCCESS) goto exr_failed;
        if (chunk.start_y < 0 || chunk.height < 1 || chunk.start_y + chunk.height > h) {
            rv = EXR_ERR_CORRUPT_CHUNK;
            goto exr_failed;
        }
        if (!decoder_live) {
            memset(&decoder, 0, sizeof decoder);
            if ((rv = exr_decoding_initialize(ctxt, 0, &chunk, &decoder)) != EXR_ERR_SUCCESS) goto exr_failed;
            decoder_live = 1;
        } else if ((rv = exr_decoding_update(ctxt, 0, &chunk, &decoder)) != EXR_ERR_SUCCESS) {
            goto exr_failed;
        }
        for (c = 0; c < decoder.channel_count; c++) {
            exr_coding_channel_info_t *ch = &decoder.channels[c];
            for (i = 0; i < nw && strcmp(ch->channel_name, names[i]) != 0; i++) continue;
            ch->decode_to_ptr = i < nw ? (uint8_t *)(node->image + (size_t)i * plane + (size_t)chunk.start_y * (size_t)w)
                                       : NULL;
            ch->user_pixel_stride = (int32_t)sizeof(float);
            ch->user_line_stride = (int32_t)(sizeof(float) * (size_t)w);
            ch->user_bytes_per_element = (int16_t)sizeof(float);
            ch->user_data_type = (uint16_t)EXR_PIXEL_FLOAT;
        }
        if (y == 0 && (rv = exr_decoding_choose_default_routines(ctxt, 0, &decoder)) != EXR_ERR_SUCCESS)
            goto exr_failed;
        if ((rv = exr_decoding_run(ctxt, 0, &decoder)) != EXR_ERR_SUCCESS) goto exr_failed;
    }
    // Every value finite and >= 0
    for (i = 0; i < nw; i++)
        for (p = 0; p < plane; p++) {
            const float v = node->image[(size_t)i * plane + p];
            if (!(isfinite(v) && v >= 0.0f)) {
                res = lensrt_fail(b->ctx, LENSRT_ERROR_PARSE,
                                  "%s: node %d (bank index %s:%d): pixel (%d, %d) of channel '%s' is %g; node values are "
                                  "finite and >= 0", path, node->k, b->index_path, node->line, (int)(p % (size_t)w),
                                  (int)(p / (size_t)w), names[i], (double)v);
                goto done;
            }
        }
    goto done;

exr_failed:
    res = lensrt_fail(b->ctx, rv == EXR_ERR_OUT_OF_MEMORY ? LENSRT_ERROR_OUT_OF_MEMORY : LENSRT_ERROR_PARSE,
                      "%s: node %d (bank index %s:%d): not a readable EXR: %s failed: OpenEXRCore says %s (%s)", path,
                      node->k, b->index_path, node->line, step, exr_get_error_code_as_string(rv),
                      exr_get_default_error_message(rv));
done:
    if (decoder_live) exr_decoding_destroy(ctxt, &decoder);
    if (ctxt) exr_finish(&ctxt);
    lensrt_free(b->ctx, names);
    lensrt_free(b->ctx, seen);
    return res;
}

#endif /* LENSRT_EXR */

/* Read node's EXR: its bytes against the index's CRC-32, then its image. */
static lensrt_result read_node(lensrt_bank b, bank_node *node)
{
    char path[2 * BANK_PATH_SIZE];
    unsigned char *bytes = NULL;
    size_t size = 0;
    uint32_t crc;
    lensrt_result res;
    snprintf(path, sizeof path, "%s%s", b->folder, node->path);
    if ((res = read_whole(b->ctx, path, "node image (EXR)", &bytes, &size)) != LENSRT_SUCCESS) {
        char why[LENSRT_ERROR_SIZE];
        snprintf(why, sizeof why, "%s", lensrt_context_last_error(b->ctx));
        return lensrt_fail(b->ctx, res, "%s (node %d, bank index %s:%d)", why, node->k, b->index_path, node->line);
    }
    // The bytes the index was written with, before anything is decoded
    crc = lensrt_crc32(bytes, size);
    if (crc != node->crc) {
        res = lensrt_fail(b->ctx, LENSRT_ERROR_PARSE,
                          "%s: node %d (bank index %s:%d): the file's CRC-32 is %08x, the index says %08x: the EXR was "
                          "changed or damaged after the bank was written; refused", path, node->k, b->index_path,
                          node->line, (unsigned)crc, (unsigned)node->crc);
    } else {
#ifdef LENSRT_EXR
        res = decode_node(b, node, path, bytes, size);
#else
        res = lensrt_fail(b->ctx, LENSRT_ERROR_UNSUPPORTED,
                          "%s: node %d (bank index %s): this lensrt was built without OpenEXR (configure with "
                          "-DLENSRT_WITH_EXR=ON), so it cannot read a bank's node images", path, node->k, b->index_path);
#endif
    }
    lensrt_free(b->ctx, bytes);
    return res;
}

/* A node's EXR is there and is a regular file (its bytes are read on first use). */
static lensrt_result stat_node(lensrt_bank b, const bank_node *node)
{
    char path[2 * BANK_PATH_SIZE];
    struct stat st;
    snprintf(path, sizeof path, "%s%s", b->folder, node->path);
    if (stat(path, &st) != 0)
        return lensrt_fail(b->ctx, LENSRT_ERROR_IO, "%s: cannot open node image (EXR): %s (node %d, bank index %s:%d)",
                           path, strerror(errno), node->k, b->index_path, node->line);
    if (!S_ISREG(st.st_mode))
        return lensrt_fail(b->ctx, LENSRT_ERROR_IO, "%s: not a regular file (node image (EXR)) (node %d, bank index %s:%d)",
                           path, node->k, b->index_path, node->line);
    return LENSRT_SUCCESS;
}

/* The node's image, read on its first use. */
static lensrt_result need_node(lensrt_bank b, bank_node *node)
{
    lensrt_result res;
    if (node->image) return LENSRT_SUCCESS;
    if ((res = read_node(b, node)) != LENSRT_SUCCESS) {
        lensrt_free(b->ctx, node->image);
        node->image = NULL;
    }
    return res;
}

/* ------------------------------------------------------------------ the API ----- */

lensrt_result lensrt_bank_load_nodes(lensrt_bank b)
{
    lensrt_result res = LENSRT_SUCCESS;
    int k;
    if (!b) return LENSRT_ERROR_INVALID_ARGUMENT;
    for (k = 0; res == LENSRT_SUCCESS && k < b->n_nodes; k++) res = need_node(b, &b->nodes[k]);
    return res;
}

void lensrt_bank_close(lensrt_bank b)
{
    int i;
    if (!b) return;
    for (i = 0; b->nodes && i < b->n_nodes; i++) {
        lensrt_free(b->ctx, b->nodes[i].chief);
        lensrt_free(b->ctx, b->nodes[i].path);
        lensrt_free(b->ctx, b->nodes[i].image);
    }
    lensrt_free(b->ctx, b->nodes);
    for (i = 0; i < N_AXES; i++) lensrt_free(b->ctx, b->values[i]);
    lensrt_free(b->ctx, b);
}

lensrt_result lensrt_bank_open(lensrt_context ctx, const char *index_path, lensrt_bank *out)
{
    lensrt_bank b;
    unsigned char *text = NULL;
    size_t size = 0, start = 0, line = 0;
    uint32_t stated = 0, actual = 0;
    bank_reader r;
    lensrt_result res;
    const char *slash;
    int k;
    if (!ctx || !index_path || !out) return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_bank_open: NULL argument");
    *out = NULL;
    if (strlen(index_path) >= BANK_PATH_SIZE)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_bank_open: the index path is longer than %d bytes",
                           BANK_PATH_SIZE - 1);
    // Read the index whole; its last line is the checksum of every byte before it
    if ((res = read_whole(ctx, index_path, "bank index", &text, &size)) != LENSRT_SUCCESS) return res;
    if (!lensrt_crc32_checksum_line((const char *)text, size, &start, &line, &stated, &actual)) {
        lensrt_free(ctx, text);
        return lensrt_fail(ctx, LENSRT_ERROR_PARSE,
                           "bank index %s:%zu: expected the last line 'checksum crc32 <8 lowercase hex digits>' (an "
                           "index cut short, or edited): refused", index_path, line);
    }
    if (stated != actual) {
        lensrt_free(ctx, text);
        return lensrt_fail(ctx, LENSRT_ERROR_PARSE,
                           "bank index %s:%zu: checksum %08x does not match the content (%08x): the index was changed "
                           "after it was written; refused", index_path, line, (unsigned)stated, (unsigned)actual);
    }
    if (!(b = lensrt_calloc(ctx, 1, sizeof *b))) {
        lensrt_free(ctx, text);
        return lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_MEMORY, "bank index %s: out of memory", index_path);
    }
    b->ctx = ctx;
    snprintf(b->index_path, sizeof b->index_path, "%s", index_path);
    // Node paths are relative to the index's folder
    slash = strrchr(index_path, '/');
    snprintf(b->folder, sizeof b->folder, "%.*s", slash ? (int)(slash - index_path + 1) : 0, index_path);
    // Parse the body, then read every node's EXR
    memset(&r, 0, sizeof r);
    r.ctx = ctx;
    r.file = b->index_path;
    r.p = (char *)text;
    r.end = (char *)text + start;
    res = read_index(&r, b);
    lensrt_free(ctx, text);
    // Each node's EXR must be a regular file now; its bytes are read, checked and decoded
    // when a query first needs the node (lensrt_bank_load_nodes: all of them now)
    for (k = 0; res == LENSRT_SUCCESS && k < b->n_nodes; k++) res = stat_node(b, &b->nodes[k]);
    if (res != LENSRT_SUCCESS) {
        lensrt_bank_close(b);
        return res;
    }
    *out = b;
    return LENSRT_SUCCESS;
}

lensrt_result lensrt_bank_get_info(lensrt_bank b, lensrt_bank_info *out)
{
    lensrt_bank_info info;
    if (!b) return LENSRT_ERROR_INVALID_ARGUMENT;
    memset(&info, 0, sizeof info);
    info.struct_size = sizeof info;
    info.lens_name = b->lens_name;
    info.table_crc32 = b->table_crc32;
    info.width = b->width;
    info.height = b->height;
    info.pixel_x_mm = b->pixel_x;
    info.pixel_y_mm = b->pixel_y;
    info.n_wavelengths = b->n[AXIS_WAVELENGTH];
    info.wavelengths_nm = b->values[AXIS_WAVELENGTH];
    info.n_f_numbers = b->n[AXIS_F];
    info.f_numbers = b->values[AXIS_F];
    info.n_focus_offsets = b->n[AXIS_FOCUS];
    info.focus_offsets_mm = b->values[AXIS_FOCUS];
    info.n_distances = b->n[AXIS_DISTANCE];
    info.distances_mm = b->values[AXIS_DISTANCE];
    info.n_field_x = b->n[AXIS_FIELD_X];
    info.field_x_deg = b->values[AXIS_FIELD_X];
    info.n_field_y = b->n[AXIS_FIELD_Y];
    info.field_y_deg = b->values[AXIS_FIELD_Y];
    info.n_nodes = b->n_nodes;
    info.worst_error_estimate = b->worst_error;
    return lensrt_struct_out(b->ctx, "lensrt_bank_info", out, &info, sizeof info);
}

/* How the bank's node images are placed (internal; lensrt_image_create needs `channel`). */
const char *lensrt_bank_registration(lensrt_bank b)
{
    return b ? REGISTRATION_NAMES[b->registration] : "";
}

/* The bank's values of an axis as text for a message: "2, 8, 16" (cut short when long). */
static void list_values(const lensrt_bank b, int axis, char *buf, size_t size)
{
    size_t used = 0;
    int i;
    buf[0] = '\0';
    for (i = 0; i < b->n[axis] && used + 32 < size; i++)
        used += (size_t)lensrt_snprintf_c(buf + used, size - used, "%s%.17g", i ? ", " : "", b->values[axis][i]);
    if (i < b->n[axis]) snprintf(buf + used, size - used, ", ...");
}

/* The slice's index on an exact axis (f-number, focus, distance): the value's place. */
static lensrt_result exact_index(lensrt_bank b, int axis, const char *name, double q, int *out)
{
    char values[512];
    int i;
    for (i = 0; i < b->n[axis]; i++)
        if (b->values[axis][i] == q) {
            *out = i;
            return LENSRT_SUCCESS;
        }
    list_values(b, axis, values, sizeof values);
    return lensrt_fail(b->ctx, LENSRT_ERROR_OUT_OF_DOMAIN, "bank %s: %s %.17g is not one of the bank's: %s", b->index_path,
                       name, q, values);
}

/* The cell of an interpolated axis (field, wavelength) holding q: its first index and the
 * weight t of the next one (0 on a grid value; one value: q must be it). */
static lensrt_result cell_of(lensrt_bank b, int axis, const char *name, double q, int *i0, double *t)
{
    const double *v = b->values[axis];
    const int n = b->n[axis];
    int lo = 0, hi = n - 1;
    if (n == 1) {
        if (q != v[0])
            return lensrt_fail(b->ctx, LENSRT_ERROR_OUT_OF_DOMAIN, "bank %s: %s %.17g: the bank holds %.17g only",
                               b->index_path, name, q, v[0]);
        *i0 = 0;
        *t = 0.0;
        return LENSRT_SUCCESS;
    }
    if (!(q >= v[0] && q <= v[n - 1]))
        return lensrt_fail(b->ctx, LENSRT_ERROR_OUT_OF_DOMAIN, "bank %s: %s %.17g is outside the bank's range [%.17g, %.17g]",
                           b->index_path, name, q, v[0], v[n - 1]);
    // Bisect for v[lo] <= q <= v[lo + 1]
    while (hi - lo > 1) {
        int mid = (lo + hi) / 2;
        if (v[mid] <= q) lo = mid;
        else hi = mid;
    }
    *i0 = lo;
    *t = q == v[lo] ? 0.0 : q == v[lo + 1] ? 1.0 : (q - v[lo]) / (v[lo + 1] - v[lo]);
    return LENSRT_SUCCESS;
}

/* One (node, channel) term of the blend: a channel plane shifted by (sx, sy) whole pixels
 * plus the bilinear taps' weights (already times the term's weight). */
typedef struct psf_term {
    const float *plane;
    long sx, sy;
    double tap[4];      /* (0, 0), (1, 0), (0, 1), (1, 1) */
} psf_term;

/* Field angles are interpolated in t = tan(angle): a lens without distortion images a
 * light at (f tan field_x, f tan field_y), so its chief point is linear in t and only
 * the distortion is left to the interpolant. */
static double tan_deg(double deg)
{
    return tan(deg * (3.14159265358979323846 / 180.0));
}

/* The weights along a field axis (of the images and of the chief points): the Lagrange
 * polynomial in t through four
 * grid values around the cell i0 (the cell's two and one on each side, or at an end of
 * the grid the four nearest: a cubic wherever the axis has 4 values; else the polynomial
 * through the 3, 2 or 1 there are). Exactly 1 and 0s on a grid value. */
static void field_weights(const double *v, int n, int i0, double q, int *first, int *count, double w[4])
{
    const int lo = n <= 4 ? 0 : i0 - 1 < 0 ? 0 : i0 - 1 > n - 4 ? n - 4 : i0 - 1;
    const int hi = n <= 4 ? n - 1 : lo + 3;
    const double tq = tan_deg(q);
    double t[4];
    int a, c;
    *first = lo;
    *count = hi - lo + 1;
    for (a = 0; a < *count; a++) t[a] = tan_deg(v[lo + a]);
    for (a = 0; a < *count; a++) {
        w[a] = 1.0;
        for (c = 0; c < *count; c++)
            if (c != a) w[a] *= (tq - t[c]) / (t[a] - t[c]);
    }
}

lensrt_result lensrt_bank_psf(lensrt_bank b, const lensrt_bank_query *query, float *out, size_t count, double chief_mm[2])
{
    lensrt_bank_query q;
    psf_term terms[32];
    const size_t plane = b ? (size_t)b->width * (size_t)b->height : 0;
    double t_unused, tl, wx[4], wy[4], centre[2] = {0.0, 0.0};
    int i_f = 0, i_z = 0, i_d = 0, ix = 0, iy = 0, il = 0, a, c, n_terms = 0, i, j;
    int x0, nx, y0, ny;
    size_t slice;
    lensrt_result res;
    if (!b) return LENSRT_ERROR_INVALID_ARGUMENT;
    if ((res = lensrt_struct_in(b->ctx, "lensrt_bank_query", query, &q, sizeof q)) != LENSRT_SUCCESS) return res;
    if (!out) return lensrt_fail(b->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "bank %s: the output is NULL", b->index_path);
    if (count != plane)
        return lensrt_fail(b->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "bank %s: count must be %zu (%d x %d pixels), got %zu",
                           b->index_path, plane, b->width, b->height, count);
    if (!isfinite(q.field_x_deg) || !isfinite(q.field_y_deg) || !isfinite(q.wavelength_nm) || !isfinite(q.f_number) ||
        !isfinite(q.focus_offset_mm) || !isfinite(q.distance_mm))
        return lensrt_fail(b->ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "bank %s: a query value is not finite (field %g, %g deg, %g nm, f/%g, focus %g mm, distance "
                           "%g mm)", b->index_path, q.field_x_deg, q.field_y_deg, q.wavelength_nm, q.f_number,
                           q.focus_offset_mm, q.distance_mm);
    // The slice: f-number (0: the first), focus offset and distance by exact match
    if (q.f_number != 0.0 && (res = exact_index(b, AXIS_F, "f_number", q.f_number, &i_f)) != LENSRT_SUCCESS) return res;
    if ((res = exact_index(b, AXIS_FOCUS, "focus_offset_mm", q.focus_offset_mm, &i_z)) != LENSRT_SUCCESS) return res;
    if ((res = exact_index(b, AXIS_DISTANCE, "distance_mm", q.distance_mm, &i_d)) != LENSRT_SUCCESS) return res;
    slice = (((size_t)i_f * (size_t)b->n[AXIS_FOCUS] + (size_t)i_z) * (size_t)b->n[AXIS_DISTANCE] + (size_t)i_d) *
            (size_t)b->n[AXIS_FIELD_Y];
    // The field cell (its weights are field_weights', below) and the wavelength's two channels
    if ((res = cell_of(b, AXIS_FIELD_X, "field_x_deg", q.field_x_deg, &ix, &t_unused)) != LENSRT_SUCCESS) return res;
    if ((res = cell_of(b, AXIS_FIELD_Y, "field_y_deg", q.field_y_deg, &iy, &t_unused)) != LENSRT_SUCCESS) return res;
    if ((res = cell_of(b, AXIS_WAVELENGTH, "wavelength_nm", q.wavelength_nm, &il, &tl)) != LENSRT_SUCCESS) return res;
    // The weights: a cubic in tan(field) over up to 4 x 4 nodes (images and chief points
    // alike), linear in wavelength
    field_weights(b->values[AXIS_FIELD_X], b->n[AXIS_FIELD_X], ix, q.field_x_deg, &x0, &nx, wx);
    field_weights(b->values[AXIS_FIELD_Y], b->n[AXIS_FIELD_Y], iy, q.field_y_deg, &y0, &ny, wy);
    for (j = 0; j < ny; j++)
        for (i = 0; i < nx; i++) {
            const bank_node *node = &b->nodes[(slice + (size_t)(y0 + j)) * (size_t)b->n[AXIS_FIELD_X] + (size_t)(x0 + i)];
            for (c = 0; c < 2; c++) {
                const double w = wy[j] * wx[i] * (c ? tl : 1.0 - tl);
                if (w == 0.0) continue;
                centre[0] += w * node->chief[2 * (il + c)];
                centre[1] += w * node->chief[2 * (il + c) + 1];
            }
        }
    // or the caller's own
    if (q.chief_given) {
        if (!isfinite(q.chief_x_mm) || !isfinite(q.chief_y_mm))
            return lensrt_fail(b->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "bank %s: the given chief point (%g, %g) mm is not "
                               "finite", b->index_path, q.chief_x_mm, q.chief_y_mm);
        centre[0] = q.chief_x_mm;
        centre[1] = q.chief_y_mm;
    }
    // The terms: up to 4 x 4 nodes x 2 channels of non-zero weight, each registered on its
    // chief point
    for (j = 0; j < ny; j++)
        for (i = 0; i < nx; i++) {
            const double wf = wy[j] * wx[i];
            bank_node *node;
            if (wf == 0.0) continue;
            node = &b->nodes[(slice + (size_t)(y0 + j)) * (size_t)b->n[AXIS_FIELD_X] + (size_t)(x0 + i)];
            if ((res = need_node(b, node)) != LENSRT_SUCCESS) return res;
            for (c = 0; c < 2; c++) {
                const double w = wf * (c ? tl : 1.0 - tl);
                const int ch = il + c;
                double ux, uy, sx = 0.0, sy = 0.0, fx, fy;
                psf_term *t;
                // (a channel of weight 0 may be past the last: a bank of one wavelength)
                if (w == 0.0) continue;
                ux = node->chief[2 * ch];
                uy = node->chief[2 * ch + 1];
                // The shift in pixels (row 0 at +y), whole and fractional parts: a node
                // centred on its middle chief point moves each channel onto its own; none
                // when each channel is centred on its own, or the nodes share one window
                if (b->registration == REGISTRATION_CHIEF) {
                    sx = (ux - node->center_x) / b->pixel_x;
                    sy = -(uy - node->center_y) / b->pixel_y;
                }
                t = &terms[n_terms++];
                t->plane = node->image + (size_t)ch * plane;
                t->sx = (long)floor(sx);
                t->sy = (long)floor(sy);
                fx = sx - floor(sx);
                fy = sy - floor(sy);
                t->tap[0] = w * (1.0 - fx) * (1.0 - fy);
                t->tap[1] = w * fx * (1.0 - fy);
                t->tap[2] = w * (1.0 - fx) * fy;
                t->tap[3] = w * fx * fy;
            }
        }
    // Each output pixel: the taps that fall inside their node image
    for (j = 0; j < b->height; j++)
        for (i = 0; i < b->width; i++) {
            double sum = 0.0;
            int k;
            for (k = 0; k < n_terms; k++)
                for (a = 0; a < 4; a++) {
                    const long x = i + terms[k].sx + a % 2, y = j + terms[k].sy + a / 2;
                    if (terms[k].tap[a] != 0.0 && x >= 0 && x < b->width && y >= 0 && y < b->height)
                        sum += terms[k].tap[a] * (double)terms[k].plane[(size_t)y * (size_t)b->width + (size_t)x];
                }
            // A cubic's weights are partly negative: irradiance is not
            out[(size_t)j * (size_t)b->width + (size_t)i] = sum > 0.0 ? (float)sum : 0.0f;
        }
    if (chief_mm) {
        chief_mm[0] = centre[0];
        chief_mm[1] = centre[1];
    }
    return LENSRT_SUCCESS;
}
