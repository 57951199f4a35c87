/* PSF banks (internal, io/bank*.c): the bank object and what its pieces share.
 *
 *   bank.c        the API: open, close, information, the PSF at a field point
 *   bank_index.c  the `lensrt-bank` index reader
 *   bank_node.c   the node images: files read whole, each EXR checked and decoded */
#ifndef LENSRT_BANK_H
#define LENSRT_BANK_H

#include "../internal.h"

#include <stddef.h>
#include <stdint.h>

/* How node images are placed (the index's `registration`): chief, each node's window on
 * its middle chief point (channels shifted on read); window, one window shared by every
 * node (blended in place); channel, each channel's window on its own chief point (read
 * with no shift at all: a node's channel is the PSF bit for bit). */
enum { REGISTRATION_CHIEF = 0, REGISTRATION_WINDOW, REGISTRATION_CHANNEL };
static const char *const REGISTRATION_NAMES[] = {"chief", "window", "channel"};

/* The grids of a bank, in the index's order after the wavelengths. */
enum { AXIS_WAVELENGTH = 0, AXIS_F, AXIS_FOCUS, AXIS_DISTANCE, AXIS_FIELD_X, AXIS_FIELD_Y, N_AXES };

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

/* Parse the index's body [body, end) (checked against its checksum line already) into b,
 * whose ctx and index_path are set: its grids, window and nodes, or the refusal with the
 * index line in the message (bank_index.c). */
lensrt_result lensrt_bank_read_index(lensrt_bank b, char *body, char *end);
/* A decimal number: digits, sign, point and exponent only (no inf, nan or hex), all of the
 * token read, finite (bank_index.c; the node EXRs' attributes too). */
int lensrt_bank_parse_number(const char *s, double *v);
/* A decimal integer in [lo, hi]: ASCII digits with an optional '-', nothing else. */
int lensrt_bank_parse_integer(const char *s, long lo, long hi, long *v);

/* A whole regular file into memory (the context's allocator); `what` names it in messages
 * (bank_node.c). */
lensrt_result lensrt_bank_read_whole(lensrt_context ctx, const char *path, const char *what, unsigned char **out,
                                     size_t *size);
/* A node's EXR is there and is a regular file (its bytes are read on first use). */
lensrt_result lensrt_bank_stat_node(lensrt_bank b, const bank_node *node);
/* The node's image, read, checked and decoded on its first use. */
lensrt_result lensrt_bank_need_node(lensrt_bank b, bank_node *node);

#endif /* LENSRT_BANK_H */
