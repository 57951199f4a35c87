/* PSF banks (lensrt.h, "PSF banks"): the API. A bank is opened from its `lensrt-bank`
 * index (io/bank_index.c; the index and each node EXR read whole and checked before
 * anything is parsed, io/bank_node.c), and the PSF at a field point and wavelength is
 * blended from the nodes around it, here.
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
#include "bank.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

/* ------------------------------------------------------------------ the API ----- */

lensrt_result lensrt_bank_load_nodes(lensrt_bank b)
{
    lensrt_result res = LENSRT_SUCCESS;
    int k;
    if (!b) return LENSRT_ERROR_INVALID_ARGUMENT;
    for (k = 0; res == LENSRT_SUCCESS && k < b->n_nodes; k++) res = lensrt_bank_need_node(b, &b->nodes[k]);
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
    lensrt_result res;
    const char *slash;
    int k;
    if (!ctx || !index_path || !out) return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_bank_open: NULL argument");
    *out = NULL;
    if (strlen(index_path) >= BANK_PATH_SIZE)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_bank_open: the index path is longer than %d bytes",
                           BANK_PATH_SIZE - 1);
    // Read the index whole; its last line is the checksum of every byte before it
    if ((res = lensrt_bank_read_whole(ctx, index_path, "bank index", &text, &size)) != LENSRT_SUCCESS) return res;
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
    res = lensrt_bank_read_index(b, (char *)text, (char *)text + start);
    lensrt_free(ctx, text);
    // Each node's EXR must be a regular file now; its bytes are read, checked and decoded
    // when a query first needs the node (lensrt_bank_load_nodes: all of them now)
    for (k = 0; res == LENSRT_SUCCESS && k < b->n_nodes; k++) res = lensrt_bank_stat_node(b, &b->nodes[k]);
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
            if ((res = lensrt_bank_need_node(b, node)) != LENSRT_SUCCESS) return res;
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
