/* test_files: what lensrt's file writers and the phasor-file reader promise (issue 14).
 *
 * Replacement (io/atomic_file.c and its users, the phasor, PNG and EXR writers): a
 * symbolic link, a FIFO, a directory or a device node at the target is refused with a
 * message naming what it is, and left as it was; an existing file's permission bits are
 * kept; temporaries `<target>.tmp-<pid>-<clock>-<attempt>` of a process that no longer
 * runs (kill -9 during a write) are removed by the next write to that target, while those
 * of live processes and of other targets are left alone.
 *
 * Phasor files (io/phasor_file.c, `lensrt-phasors 2`): every one of 40 single-bit flips
 * spread over a file is refused (checksum); files crafted with a correct checksum but 0,
 * 2^64 - 1 samples, a NaN or inf sum or version 1 are refused; sums of a table with other
 * coefficients (same lens name) are refused; a merge that would count samples twice (the
 * same file twice, a file into a resume of itself) is refused, a disjoint one accepted.
 *
 * usage: test_files LENS_TABLE SCRATCH_DIR */
#include "lensrt.h"

#include "check.h"

#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/types.h>
#include <sys/wait.h>
#include <unistd.h>

#define RESET(x) (memset(&(x), 0, sizeof(x)), (x).struct_size = sizeof(x))

/* The phasor file layout (io/phasor_file.c): samples at bytes 40..47, the checksum at
 * 88..95, the runs (24 bytes each, their count at 84..87) from 96, then the sums. */
#define SAMPLES_AT 40
#define N_RUNS_AT 84
#define CHECKSUM_AT 88
#define RUNS_AT 96

static char g_scratch[4096];
static const double WAVELENGTHS[2] = {480.0, 620.0};

static void scratch(char *out, size_t size, const char *name)
{
    snprintf(out, size, "%s/%s", g_scratch, name);
}

static unsigned char *read_all(const char *path, size_t *size)
{
    FILE *f = fopen(path, "rb");
    unsigned char *data;
    long n;
    *size = 0;
    if (!f) return NULL;
    fseek(f, 0, SEEK_END);
    n = ftell(f);
    fseek(f, 0, SEEK_SET);
    data = malloc(n > 0 ? (size_t)n + 1 : 1); /* NUL-terminated for strstr */
    if (data && fread(data, 1, (size_t)n, f) != (size_t)n) {
        free(data);
        data = NULL;
    }
    if (data) data[n > 0 ? n : 0] = 0;
    fclose(f);
    *size = data ? (size_t)n : 0;
    return data;
}

static int write_all(const char *path, const void *data, size_t size)
{
    FILE *f = fopen(path, "wb");
    int ok = f && fwrite(data, 1, size, f) == size;
    if (f) ok = (fclose(f) == 0) && ok;
    return ok;
}

/* FNV-1a 64 over the file with the checksum field taken as zero, written into that field:
 * an independent implementation of the format's checksum. */
static void fix_checksum(unsigned char *data, size_t size)
{
    uint64_t h = 0xcbf29ce484222325ULL;
    size_t i;
    memset(data + CHECKSUM_AT, 0, 8);
    for (i = 0; i < size; i++) h = (h ^ data[i]) * 0x100000001b3ULL;
    memcpy(data + CHECKSUM_AT, &h, 8);
}

/* A small scene: 16 x 16 pixels, one light at (2, 1) deg, two wavelengths, f/8. */
static lensrt_result make_render(lensrt_context ctx, lensrt_lens lens, uint64_t seed, lensrt_render *out)
{
    static lensrt_light light;
    lensrt_render_desc d;
    double xy[2] = {0, 0};
    lensrt_result res;
    RESET(light);
    light.field_x_deg = -2.0;
    light.field_y_deg = -1.0;
    *out = NULL;
    if ((res = lensrt_lens_image_point(ctx, lens, &light, 550.0, 0.0, xy)) != LENSRT_SUCCESS) return res;
    RESET(d);
    d.lens = lens;
    d.sensor.width = 16;
    d.sensor.height = 16;
    d.sensor.width_mm = 0.05;
    d.sensor.center_x_mm = xy[0];
    d.sensor.center_y_mm = xy[1];
    d.aperture.f_number = 8.0;
    d.lights = &light;
    d.n_lights = 1;
    d.wavelengths_nm = WAVELENGTHS;
    d.n_wavelengths = 2;
    d.seed = seed;
    return lensrt_render_create(ctx, &d, out);
}

static uint64_t samples_of(lensrt_render r)
{
    lensrt_render_stats s;
    RESET(s);
    return lensrt_render_get_stats(r, &s) == LENSRT_SUCCESS ? s.samples_per_wavelength : 0;
}

/* ------------------------------------------------------------ replacement ----- */

static void test_targets(lensrt_context ctx, lensrt_render r)
{
    char path[4200], real[4200], tmp[4300], other[4300];
    unsigned char *data;
    size_t size = 0;
    struct stat st;
    pid_t child;

    // A symbolic link: refused, the link and its target unchanged
    scratch(real, sizeof real, "real.phasors");
    scratch(path, sizeof path, "link.phasors");
    CHECK(write_all(real, "keep", 4), "cannot write %s", real);
    unlink(path);
    CHECK(symlink(real, path) == 0, "symlink %s: %s", path, strerror(errno));
    CHECK_RES(ctx, LENSRT_ERROR_IO, lensrt_render_save(r, path));
    CHECK_MSG(ctx, path);
    CHECK_MSG(ctx, "symbolic link");
    CHECK(lstat(path, &st) == 0 && S_ISLNK(st.st_mode), "%s is no longer a symbolic link", path);
    data = read_all(real, &size);
    CHECK(data && size == 4 && memcmp(data, "keep", 4) == 0, "the link's target %s changed", real);
    free(data);
    CHECK_RES(ctx, LENSRT_ERROR_IO, lensrt_render_write_png(r, path, 5.0));
    CHECK_MSG(ctx, "symbolic link");
    CHECK(lstat(path, &st) == 0 && S_ISLNK(st.st_mode), "PNG: %s is no longer a symbolic link", path);

    // A FIFO: refused (a rename would turn it into a regular file), still a FIFO
    scratch(path, sizeof path, "fifo.phasors");
    unlink(path);
    CHECK(mkfifo(path, 0644) == 0, "mkfifo %s: %s", path, strerror(errno));
    CHECK_RES(ctx, LENSRT_ERROR_IO, lensrt_render_save(r, path));
    CHECK_MSG(ctx, "FIFO");
    CHECK_RES(ctx, LENSRT_ERROR_IO, lensrt_render_write_png(r, path, 5.0));
    CHECK_MSG(ctx, "FIFO");
    // (a build without OpenEXR answers LENSRT_ERROR_UNSUPPORTED: either way, no write)
    CHECK(lensrt_render_write_exr(r, path) != LENSRT_SUCCESS, "EXR to the FIFO %s succeeded", path);
    CHECK(lstat(path, &st) == 0 && S_ISFIFO(st.st_mode), "%s is no longer a FIFO", path);

    // A directory
    scratch(path, sizeof path, "dir.phasors");
    CHECK(mkdir(path, 0755) == 0 || errno == EEXIST, "mkdir %s: %s", path, strerror(errno));
    CHECK_RES(ctx, LENSRT_ERROR_IO, lensrt_render_save(r, path));
    CHECK_MSG(ctx, "directory");
    CHECK(lstat(path, &st) == 0 && S_ISDIR(st.st_mode), "%s is no longer a directory", path);

    // A device node, only when not root (a regression run as root must not replace /dev/null)
    if (geteuid() != 0 && lstat("/dev/null", &st) == 0 && S_ISCHR(st.st_mode)) {
        CHECK_RES(ctx, LENSRT_ERROR_IO, lensrt_render_save(r, "/dev/null"));
        CHECK_MSG(ctx, "device node");
    }

    // The permission bits of an existing file are kept (0640, unlike the umask's default)
    scratch(path, sizeof path, "mode.phasors");
    CHECK(write_all(path, "old", 3) && chmod(path, 0640) == 0, "cannot prepare %s", path);
    CHECK_OK(ctx, lensrt_render_save(r, path));
    CHECK(stat(path, &st) == 0 && (st.st_mode & 07777) == 0640, "%s: mode %o after save, expected 640", path,
          (unsigned)(st.st_mode & 07777));
    scratch(path, sizeof path, "mode.png");
    CHECK(write_all(path, "old", 3) && chmod(path, 0600) == 0, "cannot prepare %s", path);
    CHECK_OK(ctx, lensrt_render_write_png(r, path, 5.0));
    CHECK(stat(path, &st) == 0 && (st.st_mode & 07777) == 0600, "%s: mode %o after write, expected 600", path,
          (unsigned)(st.st_mode & 07777));

    // Stale temporaries: a process that has exited (reaped, so its pid runs nothing)
    child = fork();
    if (child == 0) _exit(0);
    CHECK(child > 0 && waitpid(child, NULL, 0) == child, "fork: %s", strerror(errno));
    scratch(path, sizeof path, "stale.phasors");
    snprintf(tmp, sizeof tmp, "%s.tmp-%ld-123456-0", path, (long)child);
    CHECK(write_all(tmp, "partial", 7), "cannot write %s", tmp);
    // ... one of a live process (pid 1 always runs) and one of another target stay
    snprintf(other, sizeof other, "%s.tmp-1-123456-0", path);
    CHECK(write_all(other, "busy", 4), "cannot write %s", other);
    scratch(real, sizeof real, "unrelated.phasors");
    snprintf(real + strlen(real), sizeof real - strlen(real), ".tmp-%ld-1-0", (long)child);
    CHECK(write_all(real, "x", 1), "cannot write %s", real);
    CHECK_OK(ctx, lensrt_render_save(r, path));
    CHECK(access(tmp, F_OK) != 0, "the stale temporary %s of exited pid %ld was not removed", tmp, (long)child);
    CHECK(access(other, F_OK) == 0, "the temporary %s of a live process was removed", other);
    CHECK(access(real, F_OK) == 0, "the temporary %s of another target was removed", real);
    unlink(other);
    unlink(real);
}

/* --------------------------------------------------------- phasor files ----- */

static void test_corruption(lensrt_context ctx, lensrt_lens lens, const char *good)
{
    char path[4200];
    unsigned char *data, *copy;
    size_t size = 0, sums_at;
    lensrt_render r = NULL;
    int k, accepted = 0, n_runs = 0;
    uint64_t v;
    double x;
    data = read_all(good, &size);
    CHECK(data && size > RUNS_AT, "cannot read %s", good);
    if (!data || size <= RUNS_AT || make_render(ctx, lens, 7, &r) != LENSRT_SUCCESS) {
        free(data);
        lensrt_render_destroy(r);
        return;
    }
    copy = malloc(size);
    scratch(path, sizeof path, "bad.phasors");
    memcpy(&n_runs, data + N_RUNS_AT, 4);
    sums_at = RUNS_AT + 24 * (size_t)n_runs;

    // The untouched file and a copy with a re-computed checksum load (so the refusals
    // below come from the changes, and this test's checksum is the format's)
    CHECK_OK(ctx, lensrt_render_load(r, good));
    memcpy(copy, data, size);
    fix_checksum(copy, size);
    CHECK(memcmp(copy, data, size) == 0, "the test's FNV-1a checksum differs from the file's");

    // 40 single-bit flips at spread positions (first byte to last, bit k mod 8)
    for (k = 0; k < 40; k++) {
        size_t at = (size_t)k * (size - 1) / 39;
        memcpy(copy, data, size);
        copy[at] ^= (unsigned char)(1u << (k % 8));
        CHECK(write_all(path, copy, size), "cannot write %s", path);
        if (lensrt_render_load(r, path) == LENSRT_SUCCESS) {
            ++accepted;
            CHECK(0, "bit %d of byte %zu flipped: the file was accepted", k % 8, at);
        }
    }
    CHECK(accepted == 0, "%d of 40 single-bit flips accepted", accepted);

    // Crafted files with a correct checksum: 0 and 2^64 - 1 samples, NaN and inf sums
    for (k = 0; k < 5; k++) {
        const char *want = k < 2 ? "sample" : k < 4 ? "not finite" : "version 1";
        memcpy(copy, data, size);
        if (k < 2) {
            v = k == 0 ? 0 : UINT64_MAX;
            memcpy(copy + SAMPLES_AT, &v, 8);
        } else if (k < 4) {
            x = k == 2 ? NAN : INFINITY;
            memcpy(copy + sums_at + 8 * 17, &x, 8);
        } else {
            uint32_t one = 1;
            memcpy(copy + 16, &one, 4);
        }
        fix_checksum(copy, size);
        CHECK(write_all(path, copy, size), "cannot write %s", path);
        CHECK_RES(ctx, LENSRT_ERROR_PARSE, lensrt_render_load(r, path));
        CHECK_MSG(ctx, want);
        CHECK_RES(ctx, LENSRT_ERROR_PARSE, lensrt_render_merge(r, path));
    }
    CHECK_MSG(ctx, "render the sums again");
    free(copy);
    free(data);
    lensrt_render_destroy(r);
}

/* A copy of the table with one coefficient changed (same lens name): its sums are another
 * scene's. */
static void test_table_content(lensrt_context ctx, const char *table, const char *good)
{
    char path[4200];
    unsigned char *data;
    size_t size = 0;
    char *at;
    lensrt_lens changed = NULL;
    lensrt_render r = NULL;
    data = read_all(table, &size);
    at = data ? strstr((char *)data, "\n0 0 0 3 0 0 0.1") : NULL;
    CHECK(at != NULL, "%s: no coefficient line '0 0 0 3 0 0 0.1...' to change", table);
    if (!at) {
        free(data);
        return;
    }
    at[strlen("\n0 0 0 3 0 0 0.1")] = at[strlen("\n0 0 0 3 0 0 0.1")] == '9' ? '8' : '9';
    scratch(path, sizeof path, "changed.table");
    {
        // Stamped with its checksum, as a refit would write it (else refused at load)
        size_t n;
        char *stamped = stamp_table((const char *)data, size, &n);
        CHECK(stamped && write_all(path, stamped, n), "cannot write %s", path);
        free(stamped);
    }
    free(data);
    CHECK_OK(ctx, lensrt_lens_load(ctx, path, &changed));
    if (changed && make_render(ctx, changed, 7, &r) == LENSRT_SUCCESS) {
        CHECK_RES(ctx, LENSRT_ERROR_INCOMPATIBLE, lensrt_render_load(r, good));
        CHECK_MSG(ctx, "another scene");
        CHECK_RES(ctx, LENSRT_ERROR_INCOMPATIBLE, lensrt_render_merge(r, good));
    }
    lensrt_render_destroy(r);
    lensrt_lens_destroy(ctx, changed);
}

static void test_merge_bookkeeping(lensrt_context ctx, lensrt_lens lens, const char *a)
{
    char b[4200], m[4200];
    lensrt_render rb = NULL, r = NULL;
    scratch(b, sizeof b, "b.phasors");
    scratch(m, sizeof m, "merged.phasors");
    if (make_render(ctx, lens, 8, &rb) != LENSRT_SUCCESS) return;
    CHECK_OK(ctx, lensrt_render_run(rb, 512, NULL, NULL));
    CHECK_OK(ctx, lensrt_render_save(rb, b));

    // Resume a (seed 7), merge b (seed 8) once: 1024 samples; b again: refused
    if (make_render(ctx, lens, 7, &r) == LENSRT_SUCCESS) {
        CHECK_OK(ctx, lensrt_render_load(r, a));
        CHECK_OK(ctx, lensrt_render_merge(r, b));
        CHECK(samples_of(r) == 1024, "a + b: %llu samples, expected 1024", (unsigned long long)samples_of(r));
        CHECK_RES(ctx, LENSRT_ERROR_INCOMPATIBLE, lensrt_render_merge(r, b));
        CHECK_MSG(ctx, "counted twice");
        CHECK(samples_of(r) == 1024, "a refused merge changed the count to %llu", (unsigned long long)samples_of(r));
        // ... and the record survives a save: the merged file plus b again is refused too
        CHECK_OK(ctx, lensrt_render_save(r, m));
    }
    lensrt_render_destroy(r);
    if (make_render(ctx, lens, 9, &r) == LENSRT_SUCCESS) {
        CHECK_OK(ctx, lensrt_render_load(r, m));
        CHECK_RES(ctx, LENSRT_ERROR_INCOMPATIBLE, lensrt_render_merge(r, b));
        CHECK_RES(ctx, LENSRT_ERROR_INCOMPATIBLE, lensrt_render_merge(r, a));
    }
    lensrt_render_destroy(r);
    // A file merged into a resume of itself; a file merged twice into a fresh render
    if (make_render(ctx, lens, 7, &r) == LENSRT_SUCCESS) {
        CHECK_OK(ctx, lensrt_render_load(r, a));
        CHECK_RES(ctx, LENSRT_ERROR_INCOMPATIBLE, lensrt_render_merge(r, a));
    }
    lensrt_render_destroy(r);
    if (make_render(ctx, lens, 9, &r) == LENSRT_SUCCESS) {
        CHECK_OK(ctx, lensrt_render_merge(r, a));
        CHECK_RES(ctx, LENSRT_ERROR_INCOMPATIBLE, lensrt_render_merge(r, a));
    }
    lensrt_render_destroy(r);
    // Disjoint samples of one seed are fine: resume a with seed 8, run 256 more (seed 8
    // indices 512..767), then merge b (seed 8, indices 0..511): 1280 samples
    if (make_render(ctx, lens, 8, &r) == LENSRT_SUCCESS) {
        CHECK_OK(ctx, lensrt_render_load(r, a));
        CHECK_OK(ctx, lensrt_render_run(r, 256, NULL, NULL));
        CHECK_OK(ctx, lensrt_render_merge(r, b));
        CHECK(samples_of(r) == 1280, "a + 256 + b: %llu samples, expected 1280", (unsigned long long)samples_of(r));
    }
    lensrt_render_destroy(r);
    lensrt_render_destroy(rb);
}

int main(int argc, char **argv)
{
    lensrt_context_init init;
    lensrt_context ctx = NULL;
    lensrt_lens lens = NULL;
    lensrt_render r = NULL;
    char good[4200];
    if (argc != 3) {
        fprintf(stderr, "usage: %s LENS_TABLE SCRATCH_DIR\n", argv[0]);
        return 2;
    }
    snprintf(g_scratch, sizeof g_scratch, "%s", argv[2]);
    if (mkdir(g_scratch, 0777) != 0 && errno != EEXIST) {
        fprintf(stderr, "test_files: cannot create %s: %s\n", g_scratch, strerror(errno));
        return 2;
    }
    RESET(init);
    CHECK_RES(NULL, LENSRT_SUCCESS, lensrt_context_create(&init, &ctx));
    if (ctx) CHECK_OK(ctx, lensrt_lens_load(ctx, argv[1], &lens));
    if (lens) CHECK_OK(ctx, make_render(ctx, lens, 7, &r));
    if (r) {
        CHECK_OK(ctx, lensrt_render_run(r, 512, NULL, NULL));
        scratch(good, sizeof good, "a.phasors");
        CHECK_OK(ctx, lensrt_render_save(r, good));
        test_targets(ctx, r);
        test_corruption(ctx, lens, good);
        test_table_content(ctx, argv[1], good);
        test_merge_bookkeeping(ctx, lens, good);
    }
    lensrt_render_destroy(r);
    lensrt_lens_destroy(ctx, lens);
    lensrt_context_destroy(ctx);
    printf("test_files: %d checks, %d failed\n", g_checks, g_failures);
    return g_failures ? 1 : 0;
}
