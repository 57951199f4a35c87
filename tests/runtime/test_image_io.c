/*
 * test_image_io: CIE 1931 colour (color.c), the EXR writer (image_exr.c, read back with
 * OpenEXRCore) and the dependency-free PNG writer (image_png.c, inflated by hand). Over
 * 600 lines because checking the PNG writer independently needs its own inflater and
 * CRC (about 300 lines) next to the checks that use it.
 *
 *   test_image_io SCRATCH_DIR
 *
 * Prints every failed check with its line and returns non-zero if any failed.
 */
#include "image_io.h"

#include <dirent.h>
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <unistd.h>

#ifdef LENSRT_EXR
#include <OpenEXR/openexr.h>
#endif

/* ------------------------------------------------------------- harness ----- */

#include "check.h"

static char g_dir[4096]; /* the scratch folder */

static void scratch_path(char *out, size_t size, const char *name)
{
    snprintf(out, size, "%s/%s", g_dir, name);
}

static int file_exists(const char *path)
{
    struct stat st;
    return stat(path, &st) == 0;
}

/* Read a whole file; NULL if it cannot be read. */
static unsigned char *read_file(const char *path, size_t *size)
{
    FILE *f = fopen(path, "rb");
    unsigned char *data = NULL;
    long n;
    *size = 0;
    if (!f)
        return NULL;
    if (fseek(f, 0, SEEK_END) == 0 && (n = ftell(f)) >= 0 && fseek(f, 0, SEEK_SET) == 0) {
        data = (unsigned char *)malloc((size_t)n + 1);
        if (data && fread(data, 1, (size_t)n, f) != (size_t)n) {
            free(data);
            data = NULL;
        } else if (data)
            *size = (size_t)n;
    }
    fclose(f);
    return data;
}

static void write_text_file(const char *path, const char *text)
{
    FILE *f = fopen(path, "wb");
    if (f) {
        fputs(text, f);
        fclose(f);
    }
}

static int file_has_text(const char *path, const char *text)
{
    size_t size;
    unsigned char *data = read_file(path, &size);
    int same = data && size == strlen(text) && memcmp(data, text, size) == 0;
    free(data);
    return same;
}

/* Temporary files the writers left behind in the scratch folder ("image_io_*.tmp-*";
 * only ours, other tests may share the folder). */
static int count_temporaries(void)
{
    DIR *dir = opendir(g_dir);
    struct dirent *e;
    int n = 0;
    if (!dir)
        return -1;
    while ((e = readdir(dir)) != NULL)
        if (strncmp(e->d_name, "image_io_", 9) == 0 && strstr(e->d_name, ".tmp-"))
            ++n;
    closedir(dir);
    return n;
}

/* Simulate a full disk: cap the size of files this process writes (RLIMIT_FSIZE; writes
 * past it fail with EFBIG once SIGXFSZ is ignored). `limit` < 0 restores the old cap. */
static void limit_file_size(long limit)
{
    static struct rlimit saved;
    static int have_saved = 0;
    if (limit >= 0) {
        struct rlimit capped;
        if (getrlimit(RLIMIT_FSIZE, &saved) == 0)
            have_saved = 1;
        signal(SIGXFSZ, SIG_IGN);
        capped.rlim_cur = (rlim_t)limit;
        capped.rlim_max = have_saved ? saved.rlim_max : (rlim_t)limit;
        if (setrlimit(RLIMIT_FSIZE, &capped) != 0)
            fprintf(stderr, "warning: setrlimit(RLIMIT_FSIZE) failed: %s\n", strerror(errno));
    } else if (have_saved) {
        setrlimit(RLIMIT_FSIZE, &saved);
    }
}

/* Allocators: plain malloc, and one that fails after `budget` successful allocations. */
typedef struct test_alloc_state {
    int budget; /* allocations left before failing; < 0: never fail */
    int live;   /* allocations not yet freed */
} test_alloc_state;

static void *test_alloc(size_t size, void *user)
{
    test_alloc_state *s = (test_alloc_state *)user;
    void *p;
    if (s->budget == 0)
        return NULL;
    if (s->budget > 0)
        --s->budget;
    p = malloc(size);
    if (p)
        ++s->live;
    return p;
}

static void test_free(void *ptr, void *user)
{
    test_alloc_state *s = (test_alloc_state *)user;
    if (ptr)
        --s->live;
    free(ptr);
}

static lensrt_allocator make_allocator(test_alloc_state *state, int budget)
{
    lensrt_allocator a;
    state->budget = budget;
    state->live = 0;
    a.alloc_fn = test_alloc;
    a.free_fn = test_free;
    a.user_data = state;
    return a;
}

/* -------------------------------------------------------------- colour ----- */

static void test_colour(void)
{
    /* CIE 1931 2-degree colour matching functions, from the CIE table (CIE 015, the
     * 5 nm table of the 1931 standard observer): lambda, x-bar, y-bar, z-bar. */
    static const double table[][4] = {
        {440.0, 0.348280, 0.023000, 1.747060},
        {450.0, 0.336200, 0.038000, 1.772110},
        {500.0, 0.004900, 0.323000, 0.272000},
        {550.0, 0.433450, 0.994950, 0.008750},
        {555.0, 0.512050, 1.000000, 0.005750},
        {600.0, 1.062200, 0.631000, 0.000800},
        {650.0, 0.283500, 0.107000, 0.000000},
        {700.0, 0.011359, 0.004102, 0.000000}};
    /* Tolerance: the Wyman-Sloan-Shirley multi-lobe fit is a least-squares
     * approximation, not an interpolation of the table; its residual at these points
     * is at most 0.013 (z-bar at 440 nm, next to the z-bar peak of 1.78, i.e. 0.7 % of
     * the peak; x-bar at 600 nm is off by 0.006). 0.02 bounds that with margin and
     * still catches a wrong amplitude, centre or width (each moves some value here by
     * several hundredths). */
    const double tol_cmf = 0.02;
    double worst = 0.0;
    size_t i;
    for (i = 0; i < sizeof table / sizeof table[0]; ++i) {
        double xyz[3];
        int c;
        lensrt_cie1931_xyz(table[i][0], xyz);
        for (c = 0; c < 3; ++c) {
            double d = fabs(xyz[c] - table[i][1 + c]);
            worst = d > worst ? d : worst;
            CHECK(d <= tol_cmf, "CMF %c(%g nm) = %.6f, CIE table %.6f (tolerance %g)", "xyz"[c],
                  table[i][0], xyz[c], table[i][1 + c], tol_cmf);
        }
    }
    printf("colour: largest CMF deviation from the CIE table at %d points: %.4f\n",
           (int)(sizeof table / sizeof table[0]), worst);

    {
        /* Equal-energy white E, value 1 at 400 wavelengths 380.5, 381.5, ..., 779.5 nm
         * (1 nm cells tiling 380-780 nm exactly).
         *
         * Expected: Y = 1 by the normalisation (up to the midpoint rule on 1 nm cells,
         * far below 1e-3). E is not D65: its chromaticity is x = y = 1/3 (for the CIE
         * table the three CMF integrals are equal), while sRGB's white is D65, x = 0.3127,
         * y = 0.3290. So E is not R = G = B in sRGB: it is M (1, 1, 1) with M the
         * IEC 61966-2-1 XYZ -> sRGB matrix, (1.2048, 0.9484, 0.9087), slightly pink.
         * Tolerance 0.01: the fit's integrals of x-bar and z-bar differ from that of
         * y-bar by well under 1 % (measured; the CIE table has them equal). */
        enum { N = 400 };
        double wl[N];
        float spd[N], rgb[3];
        const double expected[3] = {3.2406 - 1.5372 - 0.4986, -0.9689 + 1.8758 + 0.0415,
                                    0.0557 - 0.2040 + 1.0570};
        double y_lum;
        int k;
        for (k = 0; k < N; ++k) {
            wl[k] = 380.5 + k;
            spd[k] = 1.0f;
        }
        lensrt_spectrum_to_rgb(N, wl, spd, 1, rgb);
        /* Y from linear sRGB: the Rec. 709 luminance row of the inverse matrix. */
        y_lum = 0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2];
        printf("colour: equal-energy white -> linear sRGB (%.4f, %.4f, %.4f), Y = %.5f\n", rgb[0],
               rgb[1], rgb[2], y_lum);
        CHECK(fabs(y_lum - 1.0) < 1e-3, "equal-energy white has Y = %.6f, expected 1", y_lum);
        for (k = 0; k < 3; ++k)
            CHECK(fabs(rgb[k] - expected[k]) < 0.01,
                  "equal-energy white channel %d = %.4f, expected M (1,1,1) = %.4f", k, rgb[k],
                  expected[k]);
        /* R > G > B by a clear margin: E is redder than D65. */
        CHECK(rgb[0] > rgb[1] + 0.2 && rgb[1] > rgb[2],
              "equal-energy white should be pink in sRGB (R > G > B)");
    }
    {
        /* The contract's 16 uniform wavelengths: bin centres 392.5 ... 767.5 nm, 25 nm
         * cells. The midpoint rule on 25 nm cells of these smooth functions keeps Y
         * within 1 % of 1. The same samples in reverse order give the same colour. */
        double wl[16], wl_rev[16];
        float spd[16], rgb[3], rgb_rev[3];
        double y_lum;
        int k;
        for (k = 0; k < 16; ++k) {
            wl[k] = 392.5 + 25.0 * k;
            wl_rev[15 - k] = wl[k];
            spd[k] = 1.0f;
        }
        lensrt_spectrum_to_rgb(16, wl, spd, 1, rgb);
        lensrt_spectrum_to_rgb(16, wl_rev, spd, 1, rgb_rev);
        y_lum = 0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2];
        CHECK(fabs(y_lum - 1.0) < 0.01, "16-wavelength equal-energy white has Y = %.5f", y_lum);
        for (k = 0; k < 3; ++k)
            CHECK(fabs(rgb[k] - rgb_rev[k]) < 1e-6f,
                  "reversed wavelength order changes channel %d: %.7f vs %.7f", k, rgb[k],
                  rgb_rev[k]);
    }
    {
        /* Two pixels, planar input: pixel 1 is twice pixel 0 (linearity). */
        double wl[3] = {450.0, 550.0, 650.0};
        float spd[6] = {0.5f, 1.0f, 0.25f, 0.5f, 2.0f, 4.0f};
        float rgb[6];
        int c;
        lensrt_spectrum_to_rgb(3, wl, spd, 2, rgb);
        for (c = 0; c < 3; ++c)
            CHECK(fabs(rgb[3 + c] - 2.0f * rgb[c]) < 1e-5f * (1.0f + fabsf(rgb[3 + c])),
                  "linearity, channel %d: %.7f vs 2 x %.7f", c, rgb[3 + c], rgb[c]);
    }
}

/* ----------------------------------------------------------------- EXR ----- */

enum { EXR_W = 7, EXR_H = 5, EXR_N = 4 };
static const double exr_wavelengths[EXR_N] = {450.0, 532.5, 610.25, 700.125};

static void fill_spectral(float *spectral, float offset)
{
    int w, p;
    for (w = 0; w < EXR_N; ++w)
        for (p = 0; p < EXR_W * EXR_H; ++p)
            spectral[w * EXR_W * EXR_H + p] = offset + 0.5f * (float)(w + 1) + 0.125f * (float)p - 1.0f;
    /* A few values that a lossy path would change: tiny, denormal, huge, negative zero. */
    spectral[0] = 1.0e-30f;
    spectral[1] = 1.0e-40f;
    spectral[2] = 3.0e38f;
    spectral[3] = -0.0f;
}

static lensrt_image_meta make_meta(const lensrt_light *lights, int n_lights)
{
    lensrt_image_meta m;
    memset(&m, 0, sizeof m);
    m.lens_name = "Test double Gauss 50 mm f/2";
    m.lens_file = NULL;
    m.focal_length_mm = 50.0;
    m.f_number = 2.0;
    m.stop_radius_mm = 12.5;
    m.focus_offset_mm = 0.01;
    m.pixel_pitch_x_mm = 0.002;
    m.pixel_pitch_y_mm = 0.003;
    m.center_x_mm = 0.5;
    m.center_y_mm = -0.25;
    m.samples_per_wavelength = 123456789012ULL;
    m.seconds = 1.5;
    m.splats_per_second = 2.0e9;
    m.sampler = "sobol";
    m.estimator = "paper";
    m.aperture = "7 blades, curvature 0.3, rotation 10 deg";
    m.seed = 18446744073709551615ULL;
    m.n_lights = n_lights;
    m.lights = lights;
    return m;
}

#ifdef LENSRT_EXR

/* Decode every chunk of part 0 into planes[k * w * h + y * w + x], channel k named
 * names[k] (channels with other names are skipped). */
static void decode_planes(exr_context_t f, int w, int h, int n_names, const char *const *names,
                          float *planes)
{
    exr_decode_pipeline_t decoder;
    int32_t lines = 0;
    int y, c, i, first = 1;
    CHECK(exr_get_scanlines_per_chunk(f, 0, &lines) == EXR_ERR_SUCCESS && lines > 0,
          "scanlines per chunk");
    for (y = 0; lines > 0 && y < h; y += lines) {
        exr_chunk_info_t chunk;
        if (exr_read_scanline_chunk_info(f, 0, y, &chunk) != EXR_ERR_SUCCESS) {
            CHECK(0, "exr_read_scanline_chunk_info(y = %d)", y);
            break;
        }
        if (first) {
            CHECK(exr_decoding_initialize(f, 0, &chunk, &decoder) == EXR_ERR_SUCCESS,
                  "exr_decoding_initialize");
        } else {
            CHECK(exr_decoding_update(f, 0, &chunk, &decoder) == EXR_ERR_SUCCESS,
                  "exr_decoding_update");
        }
        for (c = 0; c < decoder.channel_count; ++c) {
            int k = -1;
            for (i = 0; i < n_names; ++i)
                if (strcmp(decoder.channels[c].channel_name, names[i]) == 0)
                    k = i;
            if (k < 0) {
                decoder.channels[c].decode_to_ptr = NULL;
                continue;
            }
            decoder.channels[c].decode_to_ptr =
                (uint8_t *)(planes + (size_t)k * w * h + (size_t)chunk.start_y * w);
            decoder.channels[c].user_pixel_stride = (int32_t)sizeof(float);
            decoder.channels[c].user_line_stride = (int32_t)(sizeof(float) * (size_t)w);
            decoder.channels[c].user_bytes_per_element = (int16_t)sizeof(float);
            decoder.channels[c].user_data_type = (uint16_t)EXR_PIXEL_FLOAT;
        }
        if (first)
            CHECK(exr_decoding_choose_default_routines(f, 0, &decoder) == EXR_ERR_SUCCESS,
                  "exr_decoding_choose_default_routines");
        first = 0;
        CHECK(exr_decoding_run(f, 0, &decoder) == EXR_ERR_SUCCESS, "exr_decoding_run(y = %d)", y);
    }
    if (!first)
        exr_decoding_destroy(f, &decoder);
}

/* Read an EXR back with OpenEXRCore: channels sorted by name, pixels per channel. */
static void check_exr_file(const char *path, const float *spectral, const float *rgb)
{
    exr_context_t f = NULL;
    exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
    const exr_attr_chlist_t *chlist = NULL;
    const char *expected_names[EXR_N + 3] = {"B", "G", "R", "S0.450,000000nm", "S0.532,500000nm",
                                             "S0.610,250000nm", "S0.700,125000nm"};
    float planes[EXR_N + 3][EXR_W * EXR_H];
    const char *s = NULL;
    int32_t len = 0, nl = 0;
    double d = 0.0;
    float fl = 0.0f;
    exr_compression_t comp = EXR_COMPRESSION_NONE;
    exr_attr_box2i_t dw;
    exr_attr_v2d_t v2;
    exr_attr_chromaticities_t chroma;
    int c, i, mismatches = 0;

    if (exr_start_read(&f, path, &init) != EXR_ERR_SUCCESS) {
        CHECK(0, "OpenEXRCore cannot open '%s'", path);
        return;
    }
    /* Channels: the spectral layout's names, FLOAT, sorted (B G R S0...). */
    CHECK(exr_get_channels(f, 0, &chlist) == EXR_ERR_SUCCESS, "exr_get_channels");
    CHECK(chlist && chlist->num_channels == EXR_N + 3, "channel count %d, expected %d",
          chlist ? chlist->num_channels : -1, EXR_N + 3);
    if (chlist && chlist->num_channels == EXR_N + 3)
        for (i = 0; i < EXR_N + 3; ++i) {
            CHECK(strcmp(chlist->entries[i].name.str, expected_names[i]) == 0,
                  "channel %d is '%s', expected '%s'", i, chlist->entries[i].name.str,
                  expected_names[i]);
            CHECK(chlist->entries[i].pixel_type == EXR_PIXEL_FLOAT, "channel %d is not FLOAT", i);
        }
    /* Attributes: layout, standard ones, lensrt metadata. */
    CHECK(exr_attr_get_string(f, 0, "spectralLayoutVersion", &len, &s) == EXR_ERR_SUCCESS &&
              strcmp(s, "1.0") == 0,
          "spectralLayoutVersion is not the string \"1.0\"");
    /* No radiance unit: lensrt's values are relative irradiance, which lensrt/units says */
    CHECK(exr_attr_get_string(f, 0, "emissiveUnits", &len, &s) == EXR_ERR_NO_ATTR_BY_NAME,
          "emissiveUnits is present; lensrt's values are not radiance");
    CHECK(exr_attr_get_string(f, 0, "lensrt/units", &len, &s) == EXR_ERR_SUCCESS &&
              strncmp(s, "relative irradiance, dimensionless", 34) == 0,
          "lensrt/units is '%s'", s ? s : "");
    CHECK(exr_attr_get_string(f, 0, "lensrt/lens", &len, &s) == EXR_ERR_SUCCESS &&
              strcmp(s, "Test double Gauss 50 mm f/2") == 0,
          "lensrt/lens is wrong");
    CHECK(exr_attr_get_double(f, 0, "lensrt/fNumber", &d) == EXR_ERR_SUCCESS && d == 2.0,
          "lensrt/fNumber is %g, expected 2", d);
    CHECK(exr_attr_get_double(f, 0, "lensrt/focusOffsetMm", &d) == EXR_ERR_SUCCESS && d == 0.01,
          "lensrt/focusOffsetMm is %g, expected 0.01", d);
    CHECK(exr_attr_get_v2d(f, 0, "lensrt/pixelPitchMm", &v2) == EXR_ERR_SUCCESS &&
              v2.arr[0] == 0.002 && v2.arr[1] == 0.003,
          "lensrt/pixelPitchMm is wrong");
    CHECK(exr_attr_get_string(f, 0, "lensrt/samplesPerWavelength", &len, &s) == EXR_ERR_SUCCESS &&
              strcmp(s, "123456789012") == 0,
          "lensrt/samplesPerWavelength is wrong");
    CHECK(exr_attr_get_string(f, 0, "lensrt/seed", &len, &s) == EXR_ERR_SUCCESS &&
              strcmp(s, "18446744073709551615") == 0,
          "lensrt/seed is wrong");
    CHECK(exr_attr_get_int(f, 0, "lensrt/nLights", &nl) == EXR_ERR_SUCCESS && nl == 2,
          "lensrt/nLights is %d, expected 2", nl);
    CHECK(exr_attr_get_string(f, 0, "lensrt/lights", &len, &s) == EXR_ERR_SUCCESS &&
              strstr(s, "2 lights (field angles of the chief ray: +y is imaged at +y): (field 0, 0 deg; distance infinity; intensity 1); (field -1.5, "
                        "2 deg; distance 1000 mm; intensity 3)") == s,
          "lensrt/lights is '%s'", s ? s : "");
    CHECK(exr_attr_get_float(f, 0, "aperture", &fl) == EXR_ERR_SUCCESS && fl == 2.0f,
          "standard attribute aperture is %g, expected 2", (double)fl);
    CHECK(exr_attr_get_chromaticities(f, 0, "chromaticities", &chroma) == EXR_ERR_SUCCESS &&
              chroma.white_x == 0.3127f && chroma.red_x == 0.64f,
          "chromaticities are not sRGB / D65");
    CHECK(exr_attr_get_string(f, 0, "comments", &len, &s) == EXR_ERR_SUCCESS &&
              strstr(s, "4 wavelengths 450-700.125 nm") != NULL,
          "comments is '%s'", s ? s : "");
    CHECK(exr_get_compression(f, 0, &comp) == EXR_ERR_SUCCESS && comp == EXR_COMPRESSION_ZIP,
          "compression is not ZIP");
    CHECK(exr_get_data_window(f, 0, &dw) == EXR_ERR_SUCCESS && dw.min.x == 0 && dw.min.y == 0 &&
              dw.max.x == EXR_W - 1 && dw.max.y == EXR_H - 1,
          "data window is wrong");

    /* Pixels: decode every chunk into one plane per channel. */
    memset(planes, 0xFF, sizeof planes);
    decode_planes(f, EXR_W, EXR_H, EXR_N + 3, expected_names, &planes[0][0]);
    exr_finish(&f);

    /* Every value bit for bit: B G R from rgb, then the spectral planes in order. */
    for (i = 0; i < EXR_W * EXR_H; ++i) {
        for (c = 0; c < 3; ++c)
            if (memcmp(&planes[2 - c][i], &rgb[3 * i + c], sizeof(float)) != 0)
                ++mismatches;
        for (c = 0; c < EXR_N; ++c)
            if (memcmp(&planes[3 + c][i], &spectral[c * EXR_W * EXR_H + i], sizeof(float)) != 0)
                ++mismatches;
    }
    CHECK(mismatches == 0, "%d of %d values read back differ", mismatches,
          EXR_W * EXR_H * (EXR_N + 3));
}

#endif /* LENSRT_EXR */

static void test_exr(void)
{
    float spectral[EXR_N * EXR_W * EXR_H], rgb[3 * EXR_W * EXR_H];
    lensrt_light lights[2];
    lensrt_image_meta meta;
    test_alloc_state state;
    lensrt_allocator alloc = make_allocator(&state, -1);
    char path[4200], missing[4200], err[512];
    lensrt_result r;

    memset(lights, 0, sizeof lights);
    lights[1].field_x_deg = -1.5;
    lights[1].field_y_deg = 2.0;
    lights[1].distance_mm = 1000.0;
    lights[1].intensity = 3.0;
    meta = make_meta(lights, 2);
    fill_spectral(spectral, 0.0f);
    lensrt_spectrum_to_rgb(EXR_N, exr_wavelengths, spectral, EXR_W * EXR_H, rgb);
    scratch_path(path, sizeof path, "image_io_spectral.exr");
    scratch_path(missing, sizeof missing, "image_io_no_such_folder/spectral.exr");
    remove(path);

#ifndef LENSRT_EXR
    r = lensrt_write_exr(&alloc, path, EXR_W, EXR_H, EXR_N, exr_wavelengths, spectral, rgb, &meta,
                         err, sizeof err);
    CHECK(r == LENSRT_ERROR_UNSUPPORTED && strstr(err, path) != NULL,
          "EXR without OpenEXR: result %d, message '%s'", (int)r, err);
    CHECK(!file_exists(path), "EXR without OpenEXR left a file");
    printf("exr: built without OpenEXR, only the UNSUPPORTED answer was checked\n");
#else
    /* (b) Write, then read back everything. */
    r = lensrt_write_exr(&alloc, path, EXR_W, EXR_H, EXR_N, exr_wavelengths, spectral, rgb, &meta,
                         err, sizeof err);
    CHECK(r == LENSRT_SUCCESS, "lensrt_write_exr: result %d, message '%s'", (int)r, err);
    CHECK(state.live == 0, "EXR writer leaked %d allocations", state.live);
    if (r == LENSRT_SUCCESS)
        check_exr_file(path, spectral, rgb);
    CHECK(count_temporaries() == 0, "temporary files left after a successful EXR write");

    /* Overwrite the file with other values: the new content is read back. */
    fill_spectral(spectral, 10.0f);
    lensrt_spectrum_to_rgb(EXR_N, exr_wavelengths, spectral, EXR_W * EXR_H, rgb);
    r = lensrt_write_exr(&alloc, path, EXR_W, EXR_H, EXR_N, exr_wavelengths, spectral, rgb, &meta,
                         err, sizeof err);
    CHECK(r == LENSRT_SUCCESS, "EXR overwrite: result %d, message '%s'", (int)r, err);
    if (r == LENSRT_SUCCESS)
        check_exr_file(path, spectral, rgb);

    /* Several ZIP chunks (16 scanlines each; 37 rows: 3 chunks, the last one partial),
     * no metadata (meta NULL), wavelengths out of order: every value comes back. */
    {
        enum { TW = 9, TH = 37, TN = 3 };
        const double twl[TN] = {700.0, 400.0, 555.5};
        const char *const tnames[TN + 3] = {"B", "G", "R", "S0.400,000000nm", "S0.555,500000nm",
                                            "S0.700,000000nm"};
        const int plane_of_wl[TN] = {5, 3, 4}; /* twl[w] is read back as tnames[plane] */
        float *tspec = (float *)malloc(sizeof(float) * TN * TW * TH);
        float *trgb = (float *)malloc(sizeof(float) * 3 * TW * TH);
        float *tread = (float *)malloc(sizeof(float) * (TN + 3) * TW * TH);
        char tpath[4200];
        int k, bad = 0;
        exr_context_t f = NULL;
        scratch_path(tpath, sizeof tpath, "image_io_tall.exr");
        for (k = 0; k < TN * TW * TH; ++k)
            tspec[k] = (float)k * 0.001f - 0.5f;
        lensrt_spectrum_to_rgb(TN, twl, tspec, TW * TH, trgb);
        r = lensrt_write_exr(&alloc, tpath, TW, TH, TN, twl, tspec, trgb, NULL, err, sizeof err);
        CHECK(r == LENSRT_SUCCESS, "tall EXR: result %d, '%s'", (int)r, err);
        memset(tread, 0xFF, sizeof(float) * (TN + 3) * TW * TH);
        if (r == LENSRT_SUCCESS && exr_start_read(&f, tpath, NULL) == EXR_ERR_SUCCESS) {
            const exr_attribute_t *attr = NULL;
            int32_t chunks = 0;
            CHECK(exr_get_chunk_count(f, 0, &chunks) == EXR_ERR_SUCCESS && chunks == 3,
                  "tall EXR has %d chunks, expected 3", chunks);
            CHECK(exr_get_attribute_by_name(f, 0, "lensrt/lens", &attr) == EXR_ERR_NO_ATTR_BY_NAME,
                  "tall EXR without metadata has lensrt/lens");
            decode_planes(f, TW, TH, TN + 3, tnames, tread);
            exr_finish(&f);
            for (k = 0; k < TW * TH; ++k) {
                int c;
                for (c = 0; c < 3; ++c)
                    bad += memcmp(&tread[(2 - c) * TW * TH + k], &trgb[3 * k + c], sizeof(float)) != 0;
                for (c = 0; c < TN; ++c)
                    bad += memcmp(&tread[plane_of_wl[c] * TW * TH + k], &tspec[c * TW * TH + k],
                                  sizeof(float)) != 0;
            }
            CHECK(bad == 0, "tall EXR: %d values differ", bad);
        } else {
            CHECK(0, "cannot read the tall EXR back");
        }
        remove(tpath);
        free(tspec);
        free(trgb);
        free(tread);
    }

    /* (c) A missing folder: LENSRT_ERROR_IO, a message naming the path, no file. */
    r = lensrt_write_exr(&alloc, missing, EXR_W, EXR_H, EXR_N, exr_wavelengths, spectral, rgb,
                         &meta, err, sizeof err);
    CHECK(r == LENSRT_ERROR_IO, "EXR into a missing folder: result %d, expected IO", (int)r);
    CHECK(strstr(err, missing) != NULL, "EXR error message does not name the path: '%s'", err);
    CHECK(!file_exists(missing), "EXR into a missing folder left a file");
    printf("exr: missing folder -> \"%s\"\n", err);

    /* (c) Failures leave an existing file untouched and no temporary file: an allocator
     * that fails at the 1st, 2nd, ... allocation, until the write succeeds. */
    {
        char target[4200];
        int budget, failures = 0, succeeded = 0;
        scratch_path(target, sizeof target, "image_io_existing.exr");
        write_text_file(target, "sentinel\n");
        for (budget = 0; budget < 64 && !succeeded; ++budget) {
            lensrt_allocator failing = make_allocator(&state, budget);
            r = lensrt_write_exr(&failing, target, EXR_W, EXR_H, EXR_N, exr_wavelengths, spectral,
                                 rgb, &meta, err, sizeof err);
            CHECK(state.live == 0, "EXR writer leaked %d allocations (budget %d)", state.live,
                  budget);
            if (r == LENSRT_SUCCESS) {
                succeeded = 1;
                break;
            }
            ++failures;
            CHECK(r == LENSRT_ERROR_OUT_OF_MEMORY && strstr(err, target) != NULL,
                  "EXR with allocation %d failing: result %d, message '%s'", budget + 1, (int)r, err);
            CHECK(file_has_text(target, "sentinel\n"),
                  "EXR failure with allocation %d failing changed the existing file", budget + 1);
            CHECK(count_temporaries() == 0, "EXR failure (budget %d) left a temporary file", budget);
        }
        CHECK(succeeded && failures >= 3, "EXR allocation failures: %d failing cases, success %d",
              failures, succeeded);
        if (succeeded)
            check_exr_file(target, spectral, rgb);
        printf("exr: %d allocation-failure points checked, existing file untouched each time\n",
               failures);

        /* Writes that fail half-way: the disk is "full" after `limit` bytes, for limits
         * from inside the header to the last byte of the file (header, chunks, and the
         * chunk offset table written at the end all fail somewhere in this sweep). Each
         * must give an IO error naming the path, leave the existing file untouched and
         * leave no temporary file. */
        alloc = make_allocator(&state, -1);
        {
            size_t full_size = 0;
            unsigned char *full;
            long limit;
            int cases = 0;
            r = lensrt_write_exr(&alloc, target, EXR_W, EXR_H, EXR_N, exr_wavelengths, spectral,
                                 rgb, &meta, err, sizeof err);
            full = read_file(target, &full_size);
            free(full);
            CHECK(r == LENSRT_SUCCESS && full_size > 1000, "EXR reference write: %d, %zu bytes",
                  (int)r, full_size);
            for (limit = 100; limit < (long)full_size; limit += (limit + 100 < (long)full_size) ? 97 : 1) {
                write_text_file(target, "sentinel\n");
                limit_file_size(limit);
                r = lensrt_write_exr(&alloc, target, EXR_W, EXR_H, EXR_N, exr_wavelengths, spectral,
                                     rgb, &meta, err, sizeof err);
                limit_file_size(-1);
                ++cases;
                CHECK(r == LENSRT_ERROR_IO && strstr(err, target) != NULL,
                      "EXR on a disk full at %ld bytes: result %d, '%s'", limit, (int)r, err);
                CHECK(file_has_text(target, "sentinel\n"),
                      "EXR on a disk full at %ld bytes changed the existing file", limit);
                CHECK(count_temporaries() == 0, "EXR on a disk full at %ld bytes left a temporary",
                      limit);
                CHECK(state.live == 0, "EXR writer leaked %d allocations on a full disk", state.live);
                if (limit == 100 || limit + 1 == (long)full_size)
                    printf("exr: disk full at %ld of %zu bytes -> \"%s\"\n", limit, full_size, err);
            }
            printf("exr: %d full-disk cases checked\n", cases);
        }

        /* Invalid arguments: message, no change. */
        write_text_file(target, "sentinel\n");
        {
            const double twins[EXR_N] = {450.0, 450.0000001, 610.0, 700.0};
            r = lensrt_write_exr(&alloc, target, EXR_W, EXR_H, EXR_N, twins, spectral, rgb, &meta,
                                 err, sizeof err);
            CHECK(r == LENSRT_ERROR_INVALID_ARGUMENT && strstr(err, "S0.450,000000nm") != NULL,
                  "EXR with two wavelengths giving one name: result %d, '%s'", (int)r, err);
        }
        r = lensrt_write_exr(&alloc, target, EXR_W, 0, EXR_N, exr_wavelengths, spectral, rgb, &meta,
                             err, sizeof err);
        CHECK(r == LENSRT_ERROR_INVALID_ARGUMENT && strstr(err, target) != NULL,
              "EXR with height 0: result %d, '%s'", (int)r, err);
        r = lensrt_write_exr(&alloc, target, EXR_W, EXR_H, EXR_N, exr_wavelengths, NULL, rgb, &meta,
                             err, sizeof err);
        CHECK(r == LENSRT_ERROR_INVALID_ARGUMENT, "EXR with NULL spectral: result %d", (int)r);
        r = lensrt_write_exr(&alloc, NULL, EXR_W, EXR_H, EXR_N, exr_wavelengths, spectral, rgb,
                             &meta, err, sizeof err);
        CHECK(r == LENSRT_ERROR_INVALID_ARGUMENT, "EXR with NULL path: result %d", (int)r);
        r = lensrt_write_exr(NULL, target, EXR_W, EXR_H, EXR_N, exr_wavelengths, spectral, rgb,
                             &meta, err, sizeof err);
        CHECK(r == LENSRT_ERROR_INVALID_ARGUMENT, "EXR with NULL allocator: result %d", (int)r);
        CHECK(file_has_text(target, "sentinel\n"), "invalid EXR arguments changed the file");
        CHECK(count_temporaries() == 0, "invalid EXR arguments left a temporary file");
        remove(target);
    }
#endif
}

/* --------------------------------------------------------- layered EXR ----- */

#ifdef LENSRT_EXR

/* Names of a layered file's channels in the order OpenEXRCore keeps them (sorted by
 * bytes: the unprefixed B G R S0.<lambda>nm first, capitals sorting before the lower-case
 * layer names, then each layer's in the same order), for layers "" (unprefixed),
 * "direct" and "flare": out[i] has room for 96 bytes. */
static void layered_names(int n_wl, const double *wl, char (*out)[96])
{
    static const char *const prefixes[3] = {"", "direct.", "flare."};
    char base[64][32];
    int i, j, k, n = n_wl + 3;
    snprintf(base[0], 32, "B");
    snprintf(base[1], 32, "G");
    snprintf(base[2], 32, "R");
    for (i = 0; i < n_wl; ++i) { /* 6 decimals, comma: exactly the layout's spelling */
        long long micro = (long long)floor(wl[i] * 1.0e6 + 0.5);
        snprintf(base[3 + i], 32, "S0.%lld,%06lldnm", micro / 1000000, micro % 1000000);
    }
    /* The S0 names in byte order (the wavelengths need not be sorted) */
    for (i = 3; i < n; ++i)
        for (j = i + 1; j < n; ++j)
            if (strcmp(base[j], base[i]) < 0) {
                char t[32];
                memcpy(t, base[i], 32);
                memcpy(base[i], base[j], 32);
                memcpy(base[j], t, 32);
            }
    for (k = 0; k < 3; ++k)
        for (i = 0; i < n; ++i)
        {
            size_t lp = strlen(prefixes[k]); /* at most 7 + 31 bytes: fits in 96 */
            memcpy(out[k * n + i], prefixes[k], lp);
            memcpy(out[k * n + i] + lp, base[i], strlen(base[i]) + 1);
        }
}

/* Read a layered file's channel list and every plane: 1 when it has exactly `n`
 * channels named `names` (in that order, all FLOAT). planes[k * w * h + p]. */
static int read_layered(const char *path, int w, int h, int n, char (*names)[96], float *planes,
                        char *layers_attr, size_t attr_size)
{
    exr_context_t f = NULL;
    const exr_attr_chlist_t *chlist = NULL;
    const char *list[3 * (64 + 3)];
    const char *s = NULL;
    int32_t len = 0;
    int i, ok = 1;
    if (exr_start_read(&f, path, NULL) != EXR_ERR_SUCCESS) {
        CHECK(0, "OpenEXRCore cannot open '%s'", path);
        return 0;
    }
    CHECK(exr_get_channels(f, 0, &chlist) == EXR_ERR_SUCCESS && chlist, "exr_get_channels");
    ok = chlist && chlist->num_channels == n;
    CHECK(ok, "'%s' has %d channels, expected %d", path, chlist ? chlist->num_channels : -1, n);
    for (i = 0; ok && i < n; ++i) {
        CHECK(strcmp(chlist->entries[i].name.str, names[i]) == 0 &&
                  chlist->entries[i].pixel_type == EXR_PIXEL_FLOAT,
              "channel %d is '%s', expected '%s' (FLOAT)", i, chlist->entries[i].name.str, names[i]);
        ok = ok && strcmp(chlist->entries[i].name.str, names[i]) == 0;
        list[i] = names[i];
    }
    if (layers_attr) {
        layers_attr[0] = '\0';
        if (exr_attr_get_string(f, 0, "lensrt/layers", &len, &s) == EXR_ERR_SUCCESS)
            snprintf(layers_attr, attr_size, "%s", s);
    }
    if (ok)
        decode_planes(f, w, h, n, list, planes);
    exr_finish(&f);
    return ok;
}

/* lensrt_write_exr_layers on arrays: the unprefixed image and two layers come back bit for
 * bit under the documented names; bad and repeated names are refused naming the value;
 * failed writes leave an existing file as it was and no temporary file. */
static void test_exr_layers(void)
{
    enum { N = EXR_N + 3, NP = EXR_W * EXR_H };
    static float spec[3][EXR_N * NP], rgb[3][3 * NP], planes[3 * N * NP];
    char names[3 * N][96], path[4200], target[4200], err[512], attr[256];
    lensrt_exr_image images[3];
    lensrt_image_meta meta = make_meta(NULL, 0);
    test_alloc_state state;
    lensrt_allocator alloc = make_allocator(&state, -1);
    lensrt_result r;
    int k, i, c, bad = 0;

    /* Three different images: the values of the plain EXR test, shifted. */
    for (k = 0; k < 3; ++k) {
        fill_spectral(spec[k], 20.0f * (float)k);
        lensrt_spectrum_to_rgb(EXR_N, exr_wavelengths, spec[k], NP, rgb[k]);
        images[k].spectral = spec[k];
        images[k].rgb = rgb[k];
    }
    images[0].name = NULL;
    images[1].name = "direct";
    images[2].name = "flare";
    meta.layers = "direct: a.table; flare: b.table + c.table; unprefixed: their sum";
    layered_names(EXR_N, exr_wavelengths, names);
    scratch_path(path, sizeof path, "image_io_layers.exr");
    remove(path);

    /* (a) Round trip: exactly the documented channels, every value bit for bit. */
    r = lensrt_write_exr_layers(&alloc, path, EXR_W, EXR_H, EXR_N, exr_wavelengths, 3, images, &meta, err,
                                sizeof err);
    CHECK(r == LENSRT_SUCCESS, "layered EXR: result %d, '%s'", (int)r, err);
    CHECK(state.live == 0, "layered EXR writer leaked %d allocations", state.live);
    if (r == LENSRT_SUCCESS && read_layered(path, EXR_W, EXR_H, 3 * N, names, planes, attr, sizeof attr)) {
        for (k = 0; k < 3; ++k)
            for (i = 0; i < NP; ++i) {
                for (c = 0; c < 3; ++c) /* B G R first in each image's group */
                    bad += memcmp(&planes[(k * N + 2 - c) * NP + i], &rgb[k][3 * i + c], sizeof(float)) != 0;
                for (c = 0; c < EXR_N; ++c) /* the test's wavelengths are sorted already */
                    bad += memcmp(&planes[(k * N + 3 + c) * NP + i], &spec[k][c * NP + i], sizeof(float)) != 0;
            }
        CHECK(bad == 0, "layered EXR: %d of %d values differ", bad, 3 * N * NP);
        CHECK(strcmp(attr, meta.layers) == 0, "lensrt/layers is '%s'", attr);
    }
    printf("exr layers: '%s', '%s', ... '%s' (%d channels) read back bit for bit\n", names[0], names[N],
           names[3 * N - 1], 3 * N);

    /* A name of 64 characters: channel names past 31 bytes (OpenEXR's long names). */
    {
        char longest[LENSRT_MAX_LAYER_NAME + 1], want[96];
        exr_context_t f = NULL;
        const exr_attr_chlist_t *chlist = NULL;
        lensrt_exr_image two[2];
        memset(longest, 'x', LENSRT_MAX_LAYER_NAME);
        longest[LENSRT_MAX_LAYER_NAME] = '\0';
        two[0] = images[0];
        two[1] = images[1];
        two[1].name = longest;
        r = lensrt_write_exr_layers(&alloc, path, EXR_W, EXR_H, EXR_N, exr_wavelengths, 2, two, &meta, err,
                                    sizeof err);
        CHECK(r == LENSRT_SUCCESS, "layer name of %d characters: result %d, '%s'", LENSRT_MAX_LAYER_NAME, (int)r,
              err);
        snprintf(want, sizeof want, "%s.S0.700,125000nm", longest);
        if (r == LENSRT_SUCCESS && exr_start_read(&f, path, NULL) == EXR_ERR_SUCCESS) {
            CHECK(exr_get_channels(f, 0, &chlist) == EXR_ERR_SUCCESS && chlist && chlist->num_channels == 2 * N &&
                      strcmp(chlist->entries[2 * N - 1].name.str, want) == 0,
                  "long layer name: last channel '%s', expected '%s'",
                  chlist && chlist->num_channels > 0 ? chlist->entries[chlist->num_channels - 1].name.str : "",
                  want);
            exr_finish(&f);
        } else {
            CHECK(0, "cannot read the file with a long layer name");
        }
    }

    /* (b) Bad names, repeated names, two unprefixed images: refused naming the value;
     * the existing file is untouched, no temporary is left. */
    scratch_path(target, sizeof target, "image_io_layers_existing.exr");
    {
        static const char *const refused[] = {"", "di.rect", "dir ect", "flare/2", "S0", "S3", "M12", "T",
                                              "xxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxx"};
        char quoted[96];
        for (k = 0; k < (int)(sizeof refused / sizeof refused[0]); ++k) {
            lensrt_exr_image two[2];
            write_text_file(target, "sentinel\n");
            two[0] = images[0];
            two[1] = images[1];
            two[1].name = refused[k];
            r = lensrt_write_exr_layers(&alloc, target, EXR_W, EXR_H, EXR_N, exr_wavelengths, 2, two, &meta, err,
                                        sizeof err);
            snprintf(quoted, sizeof quoted, "'%s'", refused[k]);
            CHECK(r == LENSRT_ERROR_INVALID_ARGUMENT && strstr(err, quoted) && strstr(err, target),
                  "layer name %s: result %d, '%s'", quoted, (int)r, err);
            CHECK(file_has_text(target, "sentinel\n") && count_temporaries() == 0,
                  "refused layer name %s changed the file or left a temporary", quoted);
            if (k == 1)
                printf("exr layers: bad name -> \"%s\"\n", err);
        }
        images[2].name = "direct";
        r = lensrt_write_exr_layers(&alloc, target, EXR_W, EXR_H, EXR_N, exr_wavelengths, 3, images, &meta, err,
                                    sizeof err);
        CHECK(r == LENSRT_ERROR_INVALID_ARGUMENT && strstr(err, "'direct'") && strstr(err, "images 1 and 2"),
              "repeated layer name: result %d, '%s'", (int)r, err);
        images[2].name = NULL;
        images[1].name = NULL;
        r = lensrt_write_exr_layers(&alloc, target, EXR_W, EXR_H, EXR_N, exr_wavelengths, 3, images, &meta, err,
                                    sizeof err);
        CHECK(r == LENSRT_ERROR_INVALID_ARGUMENT && strstr(err, "unprefixed"),
              "two unprefixed images: result %d, '%s'", (int)r, err);
        images[1].name = "direct";
        images[2].name = "flare";
        images[2].rgb = NULL;
        r = lensrt_write_exr_layers(&alloc, target, EXR_W, EXR_H, EXR_N, exr_wavelengths, 3, images, &meta, err,
                                    sizeof err);
        CHECK(r == LENSRT_ERROR_INVALID_ARGUMENT && strstr(err, "'flare'") && strstr(err, "RGB"),
              "a layer without RGB: result %d, '%s'", (int)r, err);
        images[2].rgb = rgb[2];
        CHECK(file_has_text(target, "sentinel\n") && count_temporaries() == 0,
              "refused layers changed the file or left a temporary");
    }

    /* (c) Allocation failures at every step: the existing file stays, nothing leaks. */
    {
        int budget, failures = 0, succeeded = 0;
        for (budget = 0; budget < 64 && !succeeded; ++budget) {
            lensrt_allocator failing = make_allocator(&state, budget);
            write_text_file(target, "sentinel\n");
            r = lensrt_write_exr_layers(&failing, target, EXR_W, EXR_H, EXR_N, exr_wavelengths, 3, images, &meta,
                                        err, sizeof err);
            CHECK(state.live == 0, "layered EXR leaked %d allocations (budget %d)", state.live, budget);
            if (r == LENSRT_SUCCESS) {
                succeeded = 1;
                break;
            }
            ++failures;
            CHECK(r == LENSRT_ERROR_OUT_OF_MEMORY && strstr(err, target) != NULL,
                  "layered EXR with allocation %d failing: result %d, '%s'", budget + 1, (int)r, err);
            CHECK(file_has_text(target, "sentinel\n") && count_temporaries() == 0,
                  "layered EXR failure (budget %d) changed the file or left a temporary", budget);
        }
        CHECK(succeeded && failures >= 3, "layered EXR allocation failures: %d cases, success %d", failures,
              succeeded);
        /* A disk full half-way through the pixels: IO error, file untouched. */
        alloc = make_allocator(&state, -1);
        write_text_file(target, "sentinel\n");
        limit_file_size(2000);
        r = lensrt_write_exr_layers(&alloc, target, EXR_W, EXR_H, EXR_N, exr_wavelengths, 3, images, &meta, err,
                                    sizeof err);
        limit_file_size(-1);
        CHECK(r == LENSRT_ERROR_IO && strstr(err, target) && file_has_text(target, "sentinel\n") &&
                  count_temporaries() == 0,
              "layered EXR on a full disk: result %d, '%s'", (int)r, err);
        printf("exr layers: %d allocation-failure points and a full disk, existing file untouched\n", failures);
    }

    /* (d) Special files are never replaced: a symbolic link (and its target), a FIFO. */
    {
        char link[4200], fifo[4200];
        struct stat st;
        scratch_path(link, sizeof link, "image_io_layers_link.exr");
        scratch_path(fifo, sizeof fifo, "image_io_layers_fifo.exr");
        write_text_file(target, "sentinel\n");
        remove(link);
        remove(fifo);
        CHECK(symlink(target, link) == 0 && mkfifo(fifo, 0600) == 0, "cannot make a link and a FIFO");
        r = lensrt_write_exr_layers(&alloc, link, EXR_W, EXR_H, EXR_N, exr_wavelengths, 3, images, &meta, err,
                                    sizeof err);
        CHECK(r == LENSRT_ERROR_IO && strstr(err, link) && strstr(err, "symbolic link"),
              "layered EXR over a link: result %d, '%s'", (int)r, err);
        CHECK(lstat(link, &st) == 0 && S_ISLNK(st.st_mode) && file_has_text(target, "sentinel\n"),
              "layered EXR replaced the link or changed its target");
        r = lensrt_write_exr_layers(&alloc, fifo, EXR_W, EXR_H, EXR_N, exr_wavelengths, 3, images, &meta, err,
                                    sizeof err);
        CHECK(r == LENSRT_ERROR_IO && strstr(err, fifo) && strstr(err, "FIFO"),
              "layered EXR over a FIFO: result %d, '%s'", (int)r, err);
        CHECK(lstat(fifo, &st) == 0 && S_ISFIFO(st.st_mode), "layered EXR replaced the FIFO");
        CHECK(count_temporaries() == 0, "layered EXR over special files left a temporary");
        remove(link);
        remove(fifo);
    }
    remove(target);
    remove(path);
}

#endif /* LENSRT_EXR */

#ifdef LENSRT_TEST_RENDERS

/* lensrt_layers_write_exr on renders (the library, through its public API): an analytic
 * lens, a "direct" render and a "flare" of two renders (other lights, other seeds) over
 * the same window. Each layer holds its renders' images bit for bit, the unprefixed total
 * their sum; bad layers are refused with the library's message naming path and value. */
static void test_exr_layers_of_renders(void)
{
    enum { W = 8, H = 6, NW = 2, N = NW + 3, NP = W * H };
    static const double wl[NW] = {600.0, 500.0};
    lensrt_context ctx = NULL;
    lensrt_context_init ci = LENSRT_CONTEXT_INIT;
    lensrt_analytic_lens m = LENSRT_ANALYTIC_LENS_INIT;
    lensrt_lens lens = NULL;
    lensrt_render rs[4] = {NULL, NULL, NULL, NULL};
    lensrt_exr_layer layers[2] = {LENSRT_EXR_LAYER_INIT, LENSRT_EXR_LAYER_INIT};
    lensrt_light lights[3] = {LENSRT_LIGHT_INIT, LENSRT_LIGHT_INIT, LENSRT_LIGHT_INIT};
    static float direct[NW * NP], flare[NW * NP], total[NW * NP], planes[3 * N * NP], rgb[3][3 * NP];
    char names[3 * N][96], path[4200], target[4200], attr[512];
    lensrt_result r;
    int k, i, c;

    ci.threads = 1;
    if (lensrt_context_create(&ci, &ctx) != LENSRT_SUCCESS) {
        CHECK(0, "lensrt_context_create");
        return;
    }
    m.focal_length_mm = 50.0;
    m.sensor_distance_mm = 50.0;
    CHECK(lensrt_lens_create_analytic(ctx, &m, &lens) == LENSRT_SUCCESS, "analytic lens: %s",
          lensrt_context_last_error(ctx));
    /* Lights: on the axis (direct); off it by about a pixel, and brighter, for the flare */
    lights[1].field_x_deg = 0.003;
    lights[1].intensity = 0.5;
    lights[2].field_y_deg = -0.004;
    lights[2].intensity = 2.0;
    for (k = 0; k < 4 && lens; ++k) {
        lensrt_render_desc d = LENSRT_RENDER_DESC_INIT;
        d.lens = lens;
        d.aperture.f_number = 8.0;
        d.sensor.width = k == 3 ? W + 1 : W; /* render 3: another window */
        d.sensor.height = H;
        d.sensor.width_mm = 0.024;
        d.wavelengths_nm = wl;
        d.n_wavelengths = NW;
        d.lights = &lights[k < 3 ? k : 0];
        d.n_lights = 1;
        d.seed = 11 + (uint64_t)k;
        CHECK(lensrt_render_create(ctx, &d, &rs[k]) == LENSRT_SUCCESS &&
                  lensrt_render_run(rs[k], 512, NULL, NULL) == LENSRT_SUCCESS,
              "render %d: %s", k, lensrt_context_last_error(ctx));
    }
    if (!rs[0] || !rs[1] || !rs[2] || !rs[3])
        goto done;
    layers[0].name = "direct";
    layers[0].renders = &rs[0];
    layers[0].n_renders = 1;
    layers[1].name = "flare";
    layers[1].renders = &rs[1];
    layers[1].n_renders = 2;
    scratch_path(path, sizeof path, "image_io_render_layers.exr");
    scratch_path(target, sizeof target, "image_io_render_layers_existing.exr");
    remove(path);

    /* (a) The file: documented channels; direct = lensrt_render_image, flare and total =
     * lensrt_renders_image of their renders, bit for bit; RGB from the same spectra. */
    r = lensrt_layers_write_exr(layers, 2, path);
    CHECK(r == LENSRT_SUCCESS, "lensrt_layers_write_exr: %d, '%s'", (int)r, lensrt_context_last_error(ctx));
    CHECK(lensrt_render_image(rs[0], direct, NW * NP) == LENSRT_SUCCESS &&
              lensrt_renders_image(&rs[1], 2, flare, NW * NP) == LENSRT_SUCCESS &&
              lensrt_renders_image(rs, 3, total, NW * NP) == LENSRT_SUCCESS,
          "images: %s", lensrt_context_last_error(ctx));
    lensrt_spectrum_to_rgb(NW, wl, total, NP, rgb[0]);
    lensrt_spectrum_to_rgb(NW, wl, direct, NP, rgb[1]);
    lensrt_spectrum_to_rgb(NW, wl, flare, NP, rgb[2]);
    layered_names(NW, wl, names);
    if (r == LENSRT_SUCCESS && read_layered(path, W, H, 3 * N, names, planes, attr, sizeof attr)) {
        const float *want[3] = {total, direct, flare};
        int bad = 0, over = 0, lit = 0;
        double worst = 0.0;
        for (k = 0; k < 3; ++k)
            for (i = 0; i < NP; ++i) {
                for (c = 0; c < 3; ++c)
                    bad += memcmp(&planes[(k * N + 2 - c) * NP + i], &rgb[k][3 * i + c], sizeof(float)) != 0;
                /* S0.500 sorts before S0.600: plane 3 is wl[1], plane 4 is wl[0] */
                for (c = 0; c < NW; ++c)
                    bad += memcmp(&planes[(k * N + 3 + c) * NP + i], &want[k][(NW - 1 - c) * NP + i],
                                  sizeof(float)) != 0;
            }
        CHECK(bad == 0, "layered EXR of renders: %d values differ from the renders' images", bad);
        /* The total is the sum of direct and flare to float rounding. Each of the three
         * is a double sum rounded once to float (relative error <= 2^-24 each; the double
         * sums' own errors are ~2^-52), so with d, f the exact layer images
         * |T - (D + F)| <= 2^-24 (|d + f| + |d| + |f|) <= 2^-23 (|D| + |F|) (1 + 2^-23), and a
         * denormal's absolute rounding 2^-149 on top. */
        for (c = 0; c < NW; ++c)
            for (i = 0; i < NP; ++i) {
                double t = planes[(3 + c) * NP + i], d = planes[(N + 3 + c) * NP + i],
                       f = planes[(2 * N + 3 + c) * NP + i];
                double bound = ldexp(1.0, -23) * (fabs(d) + fabs(f)) * (1.0 + ldexp(1.0, -23)) + ldexp(1.0, -149);
                double e = fabs(t - (d + f));
                over += e > bound;
                lit += d > 0.0 && f > 0.0;
                worst = e / bound > worst ? e / bound : worst;
            }
        CHECK(over == 0, "total vs direct + flare: %d values beyond float rounding", over);
        CHECK(lit > NP / 2, "only %d of %d values have both a direct and a flare part", lit, NW * NP);
        CHECK(strstr(attr, "direct: ") == attr && strstr(attr, "; flare: ") && strstr(attr, " + "),
              "lensrt/layers is '%s'", attr);
        printf("exr layers of renders: total - (direct + flare) at most %.2f of the rounding bound; "
               "lensrt/layers '%s'\n", worst, attr);
    }

    /* (b) Refusals, each naming the path and the value, no file written: a bad name, a
     * repeated name, a render in two layers, another window; an unset struct_size. */
    {
        lensrt_exr_layer bad[2];
        write_text_file(target, "sentinel\n");
        bad[0] = layers[0];
        bad[1] = layers[1];
        bad[1].name = "fl.are";
        CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_layers_write_exr(bad, 2, target));
        CHECK_MSG(ctx, "'fl.are'");
        CHECK_MSG(ctx, target);
        bad[1].name = "direct";
        CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_layers_write_exr(bad, 2, target));
        CHECK_MSG(ctx, "both named 'direct'");
        bad[1].name = "flare";
        bad[1].renders = &rs[0]; /* the direct render again */
        bad[1].n_renders = 2;
        CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_layers_write_exr(bad, 2, target));
        CHECK_MSG(ctx, "count it twice");
        bad[1].renders = &rs[2]; /* renders 2 and 3: render 3 has another window */
        CHECK_RES(ctx, LENSRT_ERROR_INCOMPATIBLE, lensrt_layers_write_exr(bad, 2, target));
        CHECK_MSG(ctx, "9 x 6");
        bad[1] = layers[1];
        bad[1].struct_size = 0;
        CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_layers_write_exr(bad, 2, target));
        CHECK_MSG(ctx, "struct_size");
        CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_layers_write_exr(layers, 0, target));
        CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_layers_write_exr(layers, 2, NULL));
        CHECK(file_has_text(target, "sentinel\n") && count_temporaries() == 0,
              "refused layers changed the file or left a temporary");
        /* A missing folder: IO naming the path, no file */
        scratch_path(target, sizeof target, "image_io_no_such_folder/layers.exr");
        CHECK_RES(ctx, LENSRT_ERROR_IO, lensrt_layers_write_exr(layers, 2, target));
        CHECK_MSG(ctx, target);
        CHECK(!file_exists(target), "a failed layered write left '%s'", target);
    }
    remove(path);
    scratch_path(target, sizeof target, "image_io_render_layers_existing.exr");
    remove(target);
done:
    for (k = 0; k < 4; ++k)
        lensrt_render_destroy(rs[k]);
    lensrt_lens_destroy(ctx, lens);
    lensrt_context_destroy(ctx);
}

#endif /* LENSRT_TEST_RENDERS */

/* ----------------------------------------------------------------- PNG ----- */

/* An independent bitwise CRC-32 (no table), to check the writer's table version. */
static uint32_t ref_crc32(const unsigned char *data, size_t size)
{
    uint32_t c = 0xFFFFFFFFu;
    size_t i;
    int k;
    for (i = 0; i < size; ++i) {
        c ^= data[i];
        for (k = 0; k < 8; ++k)
            c = (c >> 1) ^ (0xEDB88320u & (0u - (c & 1u)));
    }
    return ~c;
}

static uint32_t be32(const unsigned char *p)
{
    return ((uint32_t)p[0] << 24) | ((uint32_t)p[1] << 16) | ((uint32_t)p[2] << 8) | p[3];
}

/* sRGB transfer curve and its inverse (IEC 61966-2-1). */
static double ref_srgb_encode(double lin)
{
    return lin <= 0.0031308 ? 12.92 * lin : 1.055 * pow(lin, 1.0 / 2.4) - 0.055;
}

static double ref_srgb_decode(unsigned char byte)
{
    double e = byte / 255.0;
    return e <= 0.04045 ? e / 12.92 : pow((e + 0.055) / 1.055, 2.4);
}

static double ref_luminance3(double r, double g, double b)
{
    return 0.2126 * r + 0.7152 * g + 0.0722 * b;
}

/* The reference tone map of one pixel (image_png.c's header), written out again for the
 * test: the desaturation factor is found by bisection on "every channel in [0, 1]"
 * rather than by the writer's closed form, so the two are independent. */
static void ref_tone_map(const float *px, double y_peak, double decades, unsigned char out[3])
{
    double lum = ref_luminance3(px[0], px[1], px[2]), v, s_fade, lo, hi, lin;
    int c, it;
    out[0] = out[1] = out[2] = 0;
    if (!(lum > 0.0) || !(y_peak > 0.0) || !(lum <= y_peak))
        return;
    v = 1.0 + log10(lum / y_peak) / decades;
    v = v < 0.0 ? 0.0 : v > 1.0 ? 1.0 : v;
    s_fade = v; /* chroma fades with the displayed luminance */
    /* Largest s in [0, s_fade] with v (1 + s (px / lum - 1)) in [0, 1] for every channel
     * (the set of such s is an interval containing 0, so bisection finds its end). */
    lo = 0.0;
    hi = s_fade;
    for (it = 0; it < 200 && hi > lo; ++it) {
        double mid = it == 0 ? s_fade : 0.5 * (lo + hi);
        int inside = 1;
        for (c = 0; c < 3; ++c) {
            lin = v * (1.0 + mid * (px[c] / lum - 1.0));
            inside = inside && lin >= 0.0 && lin <= 1.0;
        }
        if (inside)
            lo = mid;
        else
            hi = mid;
        if (it == 0 && inside)
            break;
    }
    for (c = 0; c < 3; ++c) {
        lin = v * (1.0 + lo * (px[c] / lum - 1.0));
        lin = lin < 0.0 ? 0.0 : lin > 1.0 ? 1.0 : lin;
        out[c] = (unsigned char)floor(ref_srgb_encode(lin) * 255.0 + 0.5);
    }
}

/* Parse a PNG written by lensrt_write_png: check the structure and every CRC, inflate
 * the stored blocks, check Adler-32; returns the raw scanlines (malloc) or NULL. */
static unsigned char *parse_png(const char *path, int width, int height, size_t *raw_size,
                                int *n_blocks)
{
    static const unsigned char signature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1A, '\n'};
    size_t size, pos = 8, zsize = 0, zpos, out_size = 0;
    unsigned char *file = read_file(path, &size), *z = NULL, *raw = NULL;
    int seen_ihdr = 0, seen_iend = 0, ok = 1;
    *raw_size = 0;
    *n_blocks = 0;
    if (!file) {
        CHECK(0, "cannot read PNG '%s'", path);
        return NULL;
    }
    CHECK(size >= 8 && memcmp(file, signature, 8) == 0, "PNG signature is wrong");
    z = (unsigned char *)malloc(size);
    /* Chunks: length, type, data, CRC over type and data. */
    while (ok && pos + 12 <= size && !seen_iend) {
        uint32_t len = be32(file + pos);
        const unsigned char *type = file + pos + 4;
        if (pos + 12 + len > size) {
            CHECK(0, "PNG chunk at %zu runs past the end of the file", pos);
            ok = 0;
            break;
        }
        CHECK(ref_crc32(type, 4 + (size_t)len) == be32(file + pos + 8 + len),
              "PNG chunk %.4s at offset %zu: CRC mismatch", (const char *)type, pos);
        if (memcmp(type, "IHDR", 4) == 0) {
            const unsigned char *d = file + pos + 8;
            seen_ihdr = 1;
            CHECK(pos == 8 && len == 13, "IHDR is not the first chunk or has length %u", len);
            CHECK(be32(d) == (uint32_t)width && be32(d + 4) == (uint32_t)height,
                  "IHDR size %u x %u, expected %d x %d", be32(d), be32(d + 4), width, height);
            CHECK(d[8] == 8 && d[9] == 2 && d[10] == 0 && d[11] == 0 && d[12] == 0,
                  "IHDR is not 8-bit RGB, deflate, no filter method, no interlace");
        } else if (memcmp(type, "IDAT", 4) == 0) {
            memcpy(z + zsize, file + pos + 8, len);
            zsize += len;
        } else if (memcmp(type, "IEND", 4) == 0) {
            seen_iend = 1;
            CHECK(len == 0 && pos + 12 == size, "IEND is not empty or not last");
        }
        pos += 12 + len;
    }
    CHECK(seen_ihdr && seen_iend, "PNG lacks IHDR or IEND");

    /* zlib: header, stored blocks, Adler-32 (big endian) of the inflated bytes. */
    raw = (unsigned char *)malloc(zsize + 1);
    CHECK(zsize >= 2 + 5 + 4 && (z[0] & 0x0F) == 8 && ((z[0] << 8) | z[1]) % 31 == 0 &&
              (z[1] & 0x20) == 0,
          "zlib header %02x %02x is wrong", zsize > 1 ? z[0] : 0, zsize > 1 ? z[1] : 0);
    zpos = 2;
    while (ok && zpos + 5 <= zsize) {
        unsigned hdr = z[zpos];
        unsigned len = z[zpos + 1] | (z[zpos + 2] << 8);
        unsigned nlen = z[zpos + 3] | (z[zpos + 4] << 8);
        CHECK(((hdr >> 1) & 3u) == 0, "deflate block %d is not stored", *n_blocks);
        CHECK(len == (~nlen & 0xFFFFu), "stored block %d: LEN %u, NLEN %u", *n_blocks, len, nlen);
        if (zpos + 5 + len > zsize) {
            CHECK(0, "stored block %d runs past the data", *n_blocks);
            ok = 0;
            break;
        }
        memcpy(raw + out_size, z + zpos + 5, len);
        out_size += len;
        zpos += 5 + len;
        ++*n_blocks;
        if (hdr & 1u)
            break;
    }
    if (ok) {
        uint32_t a = 1, b = 0;
        size_t i;
        for (i = 0; i < out_size; ++i) {
            a = (a + raw[i]) % 65521u;
            b = (b + a) % 65521u;
        }
        CHECK(zpos + 4 == zsize, "zlib stream has %zu bytes after the final block, expected 4",
              zsize - zpos);
        CHECK(zpos + 4 <= zsize && be32(z + zpos) == ((b << 16) | a), "Adler-32 mismatch");
    }
    CHECK(out_size == (size_t)height * (1 + 3 * (size_t)width), "inflated %zu bytes, expected %zu",
          out_size, (size_t)height * (1 + 3 * (size_t)width));
    free(file);
    free(z);
    if (!ok || out_size != (size_t)height * (1 + 3 * (size_t)width)) {
        free(raw);
        return NULL;
    }
    *raw_size = out_size;
    return raw;
}

static const unsigned char *png_pixel(const unsigned char *raw, int width, int x, int y)
{
    return raw + (size_t)y * (1 + 3 * (size_t)width) + 1 + 3 * (size_t)x;
}

static void test_png(void)
{
    test_alloc_state state;
    lensrt_allocator alloc = make_allocator(&state, -1);
    char path[4200], missing[4200], err[512];
    size_t raw_size;
    unsigned char *raw;
    lensrt_result r;
    int n_blocks, x, y;

    scratch_path(path, sizeof path, "image_io_preview.png");
    scratch_path(missing, sizeof missing, "image_io_no_such_folder/preview.png");

    {
        /* (d) 7 x 5 with known pixels; row 0 of rgb is the top row of the PNG. */
        enum { W = 7, H = 5 };
        float rgb[3 * W * H];
        unsigned char ref[3];
        int bad = 0;
        memset(rgb, 0, sizeof rgb);
#define PIX(px, py, r_, g_, b_)                                                                  \
    do {                                                                                         \
        rgb[3 * ((py) * W + (px)) + 0] = (r_);                                                   \
        rgb[3 * ((py) * W + (px)) + 1] = (g_);                                                   \
        rgb[3 * ((py) * W + (px)) + 2] = (b_);                                                   \
    } while (0)
        PIX(1, 0, 2.0f, 2.0f, 2.0f);          /* the peak, Y = 2: white */
        PIX(2, 0, 0.2f, 0.2f, 0.2f);          /* one decade below: v = 0.8, sRGB(0.8) -> 231 */
        PIX(3, 0, 2e-5f, 2e-5f, 2e-5f);       /* five decades below: black */
        PIX(0, 1, -1.0f, 0.5f, 0.0f);         /* negative red: desaturated until R >= 0 */
        PIX(1, 1, 1.0f, 0.5f, 0.25f);         /* orange, desaturated until R <= 1 */
        PIX(4, 4, (float)NAN, 1.0f, 1.0f);    /* NaN: black */
        r = lensrt_write_png(&alloc, path, W, H, rgb, 5.0, err, sizeof err);
        CHECK(r == LENSRT_SUCCESS, "lensrt_write_png: result %d, '%s'", (int)r, err);
        CHECK(state.live == 0, "PNG writer leaked %d allocations", state.live);
        raw = parse_png(path, W, H, &raw_size, &n_blocks);
        if (raw) {
            const unsigned char *p;
            for (y = 0; y < H; ++y)
                CHECK(raw[(size_t)y * (1 + 3 * W)] == 0, "row %d filter byte is not 0 (None)", y);
            p = png_pixel(raw, W, 1, 0);
            CHECK(p[0] == 255 && p[1] == 255 && p[2] == 255, "peak pixel is %d %d %d", p[0], p[1], p[2]);
            p = png_pixel(raw, W, 2, 0);
            CHECK(p[0] == 231 && p[1] == 231 && p[2] == 231, "one-decade pixel is %d %d %d", p[0],
                  p[1], p[2]);
            p = png_pixel(raw, W, 3, 0);
            CHECK(p[0] == 0 && p[1] == 0 && p[2] == 0, "five-decade pixel is %d %d %d", p[0], p[1],
                  p[2]);
            /* Y = 0.145, v = 0.772; (1/v - 1) / c_G = 0.120 < 1 / -c_R = 0.127: G reaches 1
             * first, R stays just above 0 (0.772 (1 - 0.120 * 7.90) = 0.040 -> sRGB 56),
             * B = 0.772 (1 - 0.120) = 0.679 -> 216. Per-channel clamping gave 0 255 0. */
            p = png_pixel(raw, W, 0, 1);
            CHECK(p[1] == 255 && p[0] > 40 && p[0] < 70 && p[2] > 205 && p[2] < 225,
                  "negative-red pixel is %d %d %d", p[0], p[1], p[2]);
            p = png_pixel(raw, W, 4, 4);
            CHECK(p[0] == 0 && p[1] == 0 && p[2] == 0, "NaN pixel is %d %d %d", p[0], p[1], p[2]);
            p = png_pixel(raw, W, 1, 1);
            CHECK(p[0] == 255 && p[1] > p[2] && p[2] > 0, "colour pixel is %d %d %d", p[0], p[1], p[2]);
            /* Every pixel against the reference tone map. */
            for (y = 0; y < H; ++y)
                for (x = 0; x < W; ++x) {
                    int c;
                    ref_tone_map(rgb + 3 * (y * W + x), 2.0, 5.0, ref);
                    for (c = 0; c < 3; ++c)
                        bad += png_pixel(raw, W, x, y)[c] != ref[c];
                }
            CHECK(bad == 0, "%d PNG bytes differ from the reference tone map", bad);
            free(raw);
        }
#undef PIX
    }
    {
        /* NaN, a negative or an infinite tone-map range is refused (it used to become 5
         * silently), naming the value; nothing is written. */
        const double bad_decades[3] = {NAN, -3.0, INFINITY};
        float rgb[3] = {1.0f, 1.0f, 1.0f};
        struct stat st;
        int k;
        remove(path);
        for (k = 0; k < 3; k++) {
            r = lensrt_write_png(&alloc, path, 1, 1, rgb, bad_decades[k], err, sizeof err);
            CHECK(r == LENSRT_ERROR_INVALID_ARGUMENT && strstr(err, "decades") != NULL,
                  "decades %g: result %d, '%s'", bad_decades[k], (int)r, err);
            CHECK(stat(path, &st) != 0, "decades %g: a PNG was written", bad_decades[k]);
        }
    }
    {
        /* An all-zero image: black, no division by zero. decades 0 means 5. */
        float rgb[3 * 3 * 2];
        size_t i;
        memset(rgb, 0, sizeof rgb);
        r = lensrt_write_png(&alloc, path, 3, 2, rgb, 0.0, err, sizeof err);
        CHECK(r == LENSRT_SUCCESS, "all-zero PNG: result %d, '%s'", (int)r, err);
        raw = parse_png(path, 3, 2, &raw_size, &n_blocks);
        if (raw) {
            int nonzero = 0;
            for (i = 0; i < raw_size; ++i)
                nonzero += raw[i] != 0;
            CHECK(nonzero == 0, "all-zero image gave %d non-zero bytes", nonzero);
            free(raw);
        }
    }
    {
        /* 200 x 120: 72120 raw bytes, more than one stored block (65535 at most). */
        enum { W = 200, H = 120 };
        float *rgb = (float *)malloc(sizeof(float) * 3 * W * H);
        unsigned char ref[3];
        int bad = 0;
        double y_peak = 0.0;
        for (y = 0; y < H; ++y)
            for (x = 0; x < W; ++x) {
                float *px = rgb + 3 * (y * W + x);
                double lum;
                px[0] = (float)pow(10.0, -6.0 + 6.0 * x / (W - 1.0));
                px[1] = 0.5f * px[0] * (float)(y + 1) / H;
                px[2] = 0.25f * px[0];
                lum = 0.2126 * px[0] + 0.7152 * px[1] + 0.0722 * px[2];
                y_peak = lum > y_peak ? lum : y_peak;
            }
        r = lensrt_write_png(&alloc, path, W, H, rgb, 3.0, err, sizeof err);
        CHECK(r == LENSRT_SUCCESS, "large PNG: result %d, '%s'", (int)r, err);
        raw = parse_png(path, W, H, &raw_size, &n_blocks);
        CHECK(n_blocks == 2, "large PNG has %d stored blocks, expected 2", n_blocks);
        if (raw) {
            for (y = 0; y < H; ++y)
                for (x = 0; x < W; ++x) {
                    int c;
                    ref_tone_map(rgb + 3 * (y * W + x), y_peak, 3.0, ref);
                    for (c = 0; c < 3; ++c)
                        bad += png_pixel(raw, W, x, y)[c] != ref[c];
                }
            CHECK(bad == 0, "%d bytes of the large PNG differ from the reference tone map", bad);
            free(raw);
        }
        free(rgb);
    }
    CHECK(count_temporaries() == 0, "temporary files left after PNG writes");

    {
        /* (c) Missing folder; failures leave an existing file untouched. */
        float rgb[3 * 4] = {1, 1, 1, 0.5f, 0.5f, 0.5f, 0, 0, 0, 2, 0, 0};
        char target[4200];
        int budget, failures = 0, succeeded = 0;
        r = lensrt_write_png(&alloc, missing, 2, 2, rgb, 5.0, err, sizeof err);
        CHECK(r == LENSRT_ERROR_IO && strstr(err, missing) != NULL,
              "PNG into a missing folder: result %d, '%s'", (int)r, err);
        CHECK(!file_exists(missing), "PNG into a missing folder left a file");
        printf("png: missing folder -> \"%s\"\n", err);

        scratch_path(target, sizeof target, "image_io_existing.png");
        write_text_file(target, "sentinel\n");
        for (budget = 0; budget < 16 && !succeeded; ++budget) {
            lensrt_allocator failing = make_allocator(&state, budget);
            r = lensrt_write_png(&failing, target, 2, 2, rgb, 5.0, err, sizeof err);
            CHECK(state.live == 0, "PNG writer leaked %d allocations (budget %d)", state.live, budget);
            if (r == LENSRT_SUCCESS) {
                succeeded = 1;
                break;
            }
            ++failures;
            CHECK(r == LENSRT_ERROR_OUT_OF_MEMORY && strstr(err, target) != NULL,
                  "PNG with allocation %d failing: result %d, '%s'", budget + 1, (int)r, err);
            CHECK(file_has_text(target, "sentinel\n"), "PNG failure changed the existing file");
            CHECK(count_temporaries() == 0, "PNG failure left a temporary file");
        }
        CHECK(succeeded && failures >= 2, "PNG allocation failures: %d cases, success %d", failures,
              succeeded);
        alloc = make_allocator(&state, -1);
        {
            /* A write that fails half-way: 200 x 120 is 72 KB, the disk is "full" at 1000. */
            enum { W = 200, H = 120 };
            float *big = (float *)calloc(3 * W * H, sizeof(float));
            if (big) {
                big[0] = 1.0f;
                write_text_file(target, "sentinel\n");
                limit_file_size(1000);
                r = lensrt_write_png(&alloc, target, W, H, big, 5.0, err, sizeof err);
                limit_file_size(-1);
                CHECK(r == LENSRT_ERROR_IO && strstr(err, target) != NULL,
                      "PNG on a full disk: result %d, '%s'", (int)r, err);
                CHECK(file_has_text(target, "sentinel\n"), "PNG on a full disk changed the file");
                CHECK(count_temporaries() == 0, "PNG on a full disk left a temporary file");
                printf("png: full disk -> \"%s\"\n", err);
                free(big);
            }
        }
        write_text_file(target, "sentinel\n");
        r = lensrt_write_png(&alloc, target, 0, 2, rgb, 5.0, err, sizeof err);
        CHECK(r == LENSRT_ERROR_INVALID_ARGUMENT && strstr(err, target) != NULL,
              "PNG with width 0: result %d, '%s'", (int)r, err);
        r = lensrt_write_png(&alloc, target, 2, 2, NULL, 5.0, err, sizeof err);
        CHECK(r == LENSRT_ERROR_INVALID_ARGUMENT, "PNG with NULL rgb: result %d", (int)r);
        CHECK(file_has_text(target, "sentinel\n"), "invalid PNG arguments changed the file");
        remove(target);
    }
}

/* The tone map's colour handling, through the file: saturated colours come out in gamut
 * with their hue and their displayed luminance, only as desaturated as the gamut needs;
 * greys stay grey; dim colours fade to grey; luminance order is kept. Per-channel
 * clamping (the map before this one) fails the luminance, bound and order checks.
 *
 * Tolerances: an 8-bit sRGB byte is within half a step of the exact value, which in
 * linear light is at most 0.5 / 255 * max d(linear)/d(encoded) = 0.5 / 255 * 2.27 =
 * 0.0045 per channel, so the luminance (weights summing to 1) is within 0.0045 and the
 * offset from grey (channel minus luminance) within 2 * 0.0045 * sqrt(3) = 0.016. */
#define GAMUT_LIN_TOL 0.0045
#define GAMUT_CHROMA_TOL 0.016

static void decode_pixel(const unsigned char *p, double lin[3])
{
    int c;
    for (c = 0; c < 3; ++c)
        lin[c] = ref_srgb_decode(p[c]);
}

static void test_png_gamut(void)
{
    /* Linear sRGB colours outside the gamut (negative components, as spectral colours
     * purer than the sRGB primaries give) and inside it. */
    static const double hues[][3] = {
        {3.0, -0.5, -0.2}, {-0.3, 1.2, -0.1}, {-0.2, -0.1, 4.0}, {2.0, 1.0, -0.3},
        {-0.5, 1.0, 1.5},  {1.5, -0.3, 1.5},  {1.0, 0.8, 0.6},   {0.6, 0.7, 1.0}};
    static const double levels[] = {0.95, 0.8, 0.6, 0.45, 0.3, 0.1};
    enum { N_HUES = sizeof hues / sizeof hues[0], N_LEVELS = sizeof levels / sizeof levels[0] };
    enum { N_GREYS = 13, N_ORDER = 49 };
    enum { W = N_HUES * N_LEVELS + N_GREYS + N_ORDER + 1 };
    const double decades = 5.0;
    test_alloc_state state;
    lensrt_allocator alloc = make_allocator(&state, -1);
    float rgb[3 * W];
    char path[4200], err[512];
    unsigned char *raw;
    size_t raw_size;
    int n_blocks, i, k, x = 0, hue_checked = 0, bound_checked = 0;
    unsigned lcg = 12345u;
    lensrt_result r;

    /* Pixel 0: the peak, white with Y = 1, so a pixel of luminance Y has v = 1 + log10(Y) / 5. */
    rgb[0] = rgb[1] = rgb[2] = 1.0f;
    x = 1;
    for (i = 0; i < N_HUES; ++i)
        for (k = 0; k < N_LEVELS; ++k, ++x) {
            double y_hue = ref_luminance3(hues[i][0], hues[i][1], hues[i][2]);
            double scale = pow(10.0, (levels[k] - 1.0) * decades) / y_hue;
            int c;
            for (c = 0; c < 3; ++c)
                rgb[3 * x + c] = (float)(hues[i][c] * scale);
        }
    for (i = 0; i < N_GREYS; ++i, ++x) /* greys from 1e-6 to 1 */
        rgb[3 * x] = rgb[3 * x + 1] = rgb[3 * x + 2] = (float)pow(10.0, -6.0 + i * 0.5);
    for (i = 0; i < N_ORDER; ++i, ++x) {
        /* Rising luminance (v = 0.02, 0.04, ... 0.98), pseudo-random hues, some outside
         * the gamut: r, g, b in [-0.3, 1.7) before scaling, luminance kept positive. */
        double col[3], y_col;
        int c;
        do {
            for (c = 0; c < 3; ++c) {
                lcg = lcg * 1103515245u + 12345u;
                col[c] = -0.3 + 2.0 * (double)((lcg >> 8) & 0xFFFFu) / 65536.0;
            }
            y_col = ref_luminance3(col[0], col[1], col[2]);
        } while (y_col < 0.1);
        for (c = 0; c < 3; ++c)
            rgb[3 * x + c] = (float)(col[c] * pow(10.0, (0.02 * (i + 1) - 1.0) * decades) / y_col);
    }

    scratch_path(path, sizeof path, "image_io_gamut.png");
    r = lensrt_write_png(&alloc, path, W, 1, rgb, decades, err, sizeof err);
    CHECK(r == LENSRT_SUCCESS, "gamut PNG: result %d, '%s'", (int)r, err);
    raw = parse_png(path, W, 1, &raw_size, &n_blocks);
    if (!raw)
        return;

    /* Saturated and mild colours at six levels. */
    x = 1;
    for (i = 0; i < N_HUES; ++i)
        for (k = 0; k < N_LEVELS; ++k, ++x) {
            const float *px = rgb + 3 * x;
            const unsigned char *p = png_pixel(raw, W, x, 0);
            double lum = ref_luminance3(px[0], px[1], px[2]), v = levels[k], lin[3], y_out;
            double cvec[3], dvec[3], cn = 0.0, dn = 0.0, dot = 0.0, s_fade, s_gamut = HUGE_VAL;
            int c;
            decode_pixel(p, lin);
            y_out = ref_luminance3(lin[0], lin[1], lin[2]);
            CHECK(fabs(y_out - v) <= GAMUT_LIN_TOL + 1e-9,
                  "hue %d at v = %.2f: displayed luminance %.4f (bytes %d %d %d)", i, v, y_out, p[0],
                  p[1], p[2]);
            s_fade = v;
            for (c = 0; c < 3; ++c) {
                cvec[c] = px[c] / lum - 1.0;
                dvec[c] = lin[c] - y_out;
                cn += cvec[c] * cvec[c];
                dn += dvec[c] * dvec[c];
                dot += cvec[c] * dvec[c];
                if (cvec[c] > 0.0)
                    s_gamut = fmin(s_gamut, (1.0 / v - 1.0) / cvec[c]);
                else if (cvec[c] < 0.0)
                    s_gamut = fmin(s_gamut, -1.0 / cvec[c]);
            }
            cn = sqrt(cn);
            dn = sqrt(dn);
            /* The hue: the offset from grey points the way of the input's, to within the
             * quantisation (|d| >= 0.1 and an error <= 0.016 turn it by at most 9 deg). */
            if (dn >= 0.1) {
                CHECK(dot / (cn * dn) >= 0.98, "hue %d at v = %.2f: hue turned (cos %.4f), bytes %d %d %d",
                      i, v, dot / (cn * dn), p[0], p[1], p[2]);
                ++hue_checked;
            }
            /* The chroma: exactly v * min(s_fade, s_gamut) * |c| (not less, not more). */
            CHECK(fabs(dn - v * fmin(s_fade, s_gamut) * cn) <= GAMUT_CHROMA_TOL,
                  "hue %d at v = %.2f: chroma %.4f, expected %.4f", i, v, dn,
                  v * fmin(s_fade, s_gamut) * cn);
            /* Limited by the gamut: one channel sits on its bound. */
            if (s_gamut < s_fade) {
                CHECK(p[0] == 0 || p[1] == 0 || p[2] == 0 || p[0] == 255 || p[1] == 255 || p[2] == 255,
                      "hue %d at v = %.2f: desaturated more than the gamut needs (bytes %d %d %d)", i,
                      v, p[0], p[1], p[2]);
                ++bound_checked;
            }
        }
    CHECK(hue_checked >= 20 && bound_checked >= 20, "only %d hue and %d bound checks ran",
          hue_checked, bound_checked);
    /* Greys stay grey, brighter greys brighter. */
    for (i = 0; i < N_GREYS; ++i, ++x) {
        const unsigned char *p = png_pixel(raw, W, x, 0);
        CHECK(p[0] == p[1] && p[1] == p[2], "grey %d is %d %d %d", i, p[0], p[1], p[2]);
        if (i > 0)
            CHECK(p[0] >= png_pixel(raw, W, x - 1, 0)[0], "grey %d darker than grey %d", i, i - 1);
    }
    CHECK(png_pixel(raw, W, x - 1, 0)[0] == 255, "the grey at the peak is not white");
    /* Luminance order: steps of 0.02 in v against a quantisation error of 2 * 0.0045. */
    {
        double previous = -1.0;
        for (i = 0; i < N_ORDER; ++i, ++x) {
            double lin[3], y_out;
            decode_pixel(png_pixel(raw, W, x, 0), lin);
            y_out = ref_luminance3(lin[0], lin[1], lin[2]);
            CHECK(y_out > previous, "order pixel %d: luminance %.4f not above %.4f", i, y_out, previous);
            CHECK(fabs(y_out - 0.02 * (i + 1)) <= GAMUT_LIN_TOL + 1e-9,
                  "order pixel %d: luminance %.4f, expected %.2f", i, y_out, 0.02 * (i + 1));
            previous = y_out;
        }
    }
    /* And the file as a whole against the reference map. */
    {
        int bad = 0, c;
        unsigned char ref[3];
        for (x = 0; x < W; ++x) {
            ref_tone_map(rgb + 3 * x, 1.0, decades, ref);
            for (c = 0; c < 3; ++c)
                bad += png_pixel(raw, W, x, 0)[c] != ref[c];
        }
        CHECK(bad == 0, "%d bytes of the gamut PNG differ from the reference tone map", bad);
    }
    free(raw);
    remove(path);
}

int main(int argc, char **argv)
{
    if (argc < 2) {
        fprintf(stderr, "usage: %s SCRATCH_DIR\n", argv[0]);
        return 2;
    }
    snprintf(g_dir, sizeof g_dir, "%s", argv[1]);
    if (mkdir(g_dir, 0777) != 0 && errno != EEXIST) {
        fprintf(stderr, "cannot create the scratch folder '%s': %s\n", g_dir, strerror(errno));
        return 2;
    }
    test_colour();
    test_exr();
#ifdef LENSRT_EXR
    test_exr_layers();
#endif
#ifdef LENSRT_TEST_RENDERS
    test_exr_layers_of_renders();
#endif
    test_png();
    test_png_gamut();
    printf("test_image_io: %d checks, %d failed\n", g_checks, g_failures);
    return g_failures == 0 ? 0 : 1;
}
