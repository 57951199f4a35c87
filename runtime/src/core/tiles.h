/* Host-scheduled tiles (internal, core/tiles.c): the session between
 * lensrt_render_tiles_begin and lensrt_render_tiles_end. */
#ifndef LENSRT_TILES_H
#define LENSRT_TILES_H

#include "render.h"

/* Samples the tiles share: the device's prepared samples of one (pass, wavelength) of the
 * session, slot pass * n_wl + wavelength, made once and read by every tile. At most
 * LENSRT_TILES_SHARED_BYTES in all and LENSRT_TILES_SLOTS slots; beyond either, tiles
 * prepare the samples themselves (same bits, more time). */
#ifndef LENSRT_TILES_SHARED_BYTES /* a build may lower it, e.g. to test private preparation */
#define LENSRT_TILES_SHARED_BYTES ((uint64_t)512 << 20)
#endif
#define LENSRT_TILES_SLOTS 65536

/* A slot's life: EMPTY; CLAIMED by the one tile that allocates its data; OPEN while tiles
 * take its chunks (next) and prepare them (done); ready for reading once done reaches the
 * chunks; PRIVATE when its data could not be had (cap or allocation): every tile then
 * prepares its own. Fields are read and written with the operations of atomic.h. */
enum { LENSRT_SLOT_EMPTY, LENSRT_SLOT_CLAIMED, LENSRT_SLOT_OPEN, LENSRT_SLOT_PRIVATE };
typedef struct lensrt_tiles_slot {
    int32_t state;
    int32_t next, done;        /* chunks taken, chunks prepared */
    void *data;                /* written once by the claimer, before it opens the slot */
} lensrt_tiles_slot;

typedef struct lensrt_tiles {
    uint64_t first, count;     /* the sample range [first, first + count) per wavelength */
    /* the samples of the last run's partial block drawn again (first is that block's
     * start: lensrt_tail_rewind), and when the range ends inside a block, the sums
     * before that block, written by each tile for its pixels (the render's tail at end) */
    uint64_t redo;
    double *tail_sum, *tail_sumsq;
    lensrt_tiles_slot *slots;  /* the shared samples (n_slots), allocated at begin */
    size_t n_slots;
    uint64_t shared_bytes;     /* data the slots have taken (atomic) */
    double t0;                 /* lensrt_seconds() at begin */
    uint32_t *cover;           /* per pixel: how many tiles claimed it (atomic) */
    double *sum0, *sumsq0;     /* the sums at begin, put back when the session fails */
    /* the pixels' set-up statistics of one pass, integers summed atomically by the tiles */
    uint64_t terms, clip, tau, dark;
    /* A cells session (lensrt_render_tiles_begin_cells): its rings (0: a samples
     * session), the meshes and the fields the tiles write (job, pixel by pixel) */
    int cells_rings, cells_estimate;
    struct lensrt_cells_job *job;
    /* A Fourier session (lensrt_render_tiles_begin_fourier): its nodes (0: none), the
     * rules and fields of its levels (fjob) and the rules themselves */
    int fourier_nodes;
    struct lensrt_fourier_job *fjob;
    struct lensrt_quadrature *fquad;
    int32_t failed;            /* turned to 1 by the first failing tile (atomic) */
    lensrt_result failure;     /* its result and message, written by that tile only */
    char message[LENSRT_ERROR_SIZE];
} lensrt_tiles;

/* Record a tile's failure and return `result`. The first failure of the session is kept
 * (for tiles_end to report); safe from any thread; never writes the context's error. */
lensrt_result lensrt_tiles_fail(lensrt_render r, lensrt_result result, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 3, 4)))
#endif
    ;
/* Prepare chunk `chunk` of a slot's data (a device's samples of one pass and wavelength,
 * job saying which); chunks write disjoint bytes. */
typedef void (*lensrt_tiles_prepare_fn)(lensrt_render r, void *data, int chunk, const void *job);
/* The shared data of slot `slot` (pass * n_wl + wavelength): `bytes` made of `n_chunks`
 * chunks. The first tile to reach the slot allocates it; every tile that reaches it
 * before it is ready prepares chunks that no other tile has taken, then waits for those
 * that others are preparing (one chunk at most each), so the samples are prepared once
 * and on as many threads as arrive. Returns the data, ready (to read only: other tiles
 * read it too), or NULL when the slot is not shared (the cap, or out of memory): the
 * caller prepares its own. Any thread; the same job for every caller of a slot. */
void *lensrt_tiles_shared(lensrt_render r, uint64_t slot, size_t bytes, int n_chunks,
                          lensrt_tiles_prepare_fn prepare, const void *job);
/* Add a tile's pixel set-up statistics (over its pixels and every wavelength, one pass). */
void lensrt_tiles_add_stats(lensrt_render r, uint64_t terms, uint64_t clip, uint64_t tau, uint64_t dark);
/* LENSRT_SUCCESS when no tile session is open; else `what` is refused (message in the
 * context: called on the render's own thread). */
lensrt_result lensrt_tiles_idle(lensrt_render r, const char *what);
/* Free an open session and its shared samples without committing it (render destruction,
 * failed sessions, tiles_end). */
void lensrt_tiles_free(lensrt_render r);

#endif /* LENSRT_TILES_H */
