/*
 * lensrt: spectral Huygens point spread functions from fitted lens polynomials.
 *
 * The paper's integrator (Monte Carlo over the aperture, phasors per wavelength in a
 * complex framebuffer, the transport after the aperture shared by every pixel) as a
 * C99 library:
 *
 *   lensrt_context     allocator and log hooks, the last error message; no globals
 *   lensrt_lens        a lens: a fitted polynomial table (generated/<lens>/lens<ID>.table)
 *                      or an analytic one (free space or a perfect thin lens)
 *   lensrt_render      a prepared scene plus its phasor sums; run() adds samples,
 *                      on the CPU (OpenMP) or on an OpenGL 4.3 device (compute shaders)
 *
 * Every call returns a lensrt_result; lensrt_result_string() names it and
 * lensrt_context_last_error() says what was wrong (file, key, value). Option structs
 * are zero-initialised to mean the documented defaults. Memory passed in is owned by
 * the caller; memory the library allocates goes through the context's hooks.
 *
 * Thread model (what may be shared between threads):
 *   lensrt_lens     immutable once made: any number of threads may use one lens at once
 *                   (renders, lensrt_lens_eval, the info calls). Destroy it last.
 *   lensrt_context  one thread at a time: it holds the last error message and the GL
 *                   device. Separate contexts may be used on separate threads at once.
 *                   Calls that accept a NULL context record no message.
 *   lensrt_render   one thread at a time, except lensrt_render_tile, which any number of
 *                   threads may call at once for disjoint rectangles between
 *                   lensrt_render_tiles_begin and lensrt_render_tiles_end. run() uses
 *                   OpenMP threads inside (lensrt_context_init.threads).
 * The library keeps no global or static mutable state and changes nothing process-wide:
 * numbers are read and written in the "C" locale on the calling thread only (whatever
 * the host's setlocale), tables are tokenised reentrantly, the GL device is made current
 * around each call that uses it and the caller's current EGL context is restored after,
 * and an EGL display or GLFW that the host initialised is never terminated. Renders are
 * deterministic for a seed whatever the number of threads or tiles.
 *
 * Units: millimetres for lengths, nanometres for wavelengths, degrees for angles.
 */
#ifndef LENSRT_H
#define LENSRT_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* ------------------------------------------------------- version and ABI ----- */

/* The version of this header (CMake's project version is read from these lines).
 * lensrt_version() is the version of the library actually loaded: the two may differ
 * when a program built against one header runs with a newer shared library, which the
 * versioned structs below allow within one major version. */
#define LENSRT_VERSION_MAJOR 0
#define LENSRT_VERSION_MINOR 12
#define LENSRT_VERSION_PATCH 0
#define LENSRT_VERSION \
    ((uint32_t)LENSRT_VERSION_MAJOR * 1000000u + (uint32_t)LENSRT_VERSION_MINOR * 1000u + \
     (uint32_t)LENSRT_VERSION_PATCH)

/* Symbols of the library. Build or link the static library with LENSRT_STATIC defined;
 * LENSRT_BUILDING is defined while lensrt itself is compiled. */
#if defined(LENSRT_STATIC)
#define LENSRT_API
#elif defined(_WIN32) || defined(__CYGWIN__)
#if defined(LENSRT_BUILDING)
#define LENSRT_API __declspec(dllexport)
#else
#define LENSRT_API __declspec(dllimport)
#endif
#elif defined(LENSRT_BUILDING) && defined(__GNUC__)
#define LENSRT_API __attribute__((visibility("default")))
#else
#define LENSRT_API
#endif

/* LENSRT_VERSION of the loaded library, and the same as "MAJOR.MINOR.PATCH". */
LENSRT_API uint32_t lensrt_version(void);
LENSRT_API const char *lensrt_version_string(void);

/* ABI rules. Every struct the caller fills or the library fills starts with
 * `size_t struct_size`, which the caller sets to sizeof the struct it was compiled with
 * (the LENSRT_*_INIT macros do, and zero every other field, which means the documented
 * defaults). The library reads and writes only the bytes struct_size covers: fields a
 * caller built against an older header does not have take their defaults on input and
 * are not written on output. A struct from a newer header (struct_size larger than this
 * library knows) is accepted when the bytes this library does not know are all zero,
 * and refused otherwise. struct_size 0 (a struct zeroed without its INIT macro) is
 * refused with a message. Structs embedded in others (lensrt_sensor,
 * lensrt_aperture) are fixed: new fields go at the end of the outer struct. Enumerated
 * values travel in int32_t fields, so their size does not depend on the compiler.
 * Arrays of versioned structs (lights) are read with the first element's struct_size as
 * the stride, and every element must carry the same size. */

/* Limits of this version. */
#define LENSRT_MAX_LIGHTS 64            /* lights per render */
#define LENSRT_MAX_WAVELENGTHS 4096     /* wavelengths per render */
#define LENSRT_MAX_RESOLUTION 65536     /* pixels per side of the window */
#define LENSRT_MAX_BLADES 64            /* aperture blades */
#define LENSRT_MAX_DEGREE 15            /* highest exponent of one input in a lens table,
                                           and highest total degree of the stop monomials */
#define LENSRT_MAX_TERMS 1000000        /* terms of one output of a lens table */
#define LENSRT_MAX_LAYER_NAME 64        /* characters of an EXR layer's name (lensrt_exr_layer) */
#define LENSRT_MAX_LAYERS 64            /* layers of one EXR (lensrt_layers_write_exr) */
/* A lens table's outputs are bounded inside their domain by the sum of their |coefficients|
 * (every monomial of normalised inputs is at most 1 there); the reader refuses a table
 * whose sums exceed these (the shipped lenses have at most 225 and 2.3). */
#define LENSRT_MAX_COEFFICIENT_SUM 1e6  /* positions and optical path lengths, mm */
#define LENSRT_MAX_TRANSMITTANCE_SUM 1e2 /* tau_o, tau_i */
/* The front group's flux per unit stop area relative to the light's irradiance on the
 * first vertex plane (the ray density of the path from the light: the entrance pupil's
 * magnification squared for a direct path, 2.97 for lens 0001) is taken as at most this:
 * only a caustic of a ghost's mapping could reach it. */
#define LENSRT_MAX_FLUX 1e2
/* Largest light intensity. A sample's phasor is at most sqrt(intensity * tau_o * flux *
 * tau_i) <= sqrt(intensity * LENSRT_MAX_FLUX) * LENSRT_MAX_TRANSMITTANCE_SUM, and the
 * kernel sums 256 of them (and their squares, for the unbiased estimator) in float:
 * 256 * 1e30 * 1e2 * 1e4 = 2.6e38 stays below FLT_MAX (3.4e38). The image itself is the intensity times the pixel's gain, up to
 * about (stop area / (wavelength x sensor distance))^2 at a focus (1.4e8 for lens 0001
 * wide open, far more for an analytic lens with a large stop): a pixel beyond FLT_MAX
 * is refused by lensrt_render_image (and _rgb and the writers), never handed out as inf. */
#define LENSRT_MAX_INTENSITY 1e30

/* ---------------------------------------------------------------- results ----- */

/* A fixed-width result code; the named values follow (new ones may be added). */
typedef int32_t lensrt_result;
enum lensrt_result_code {
    LENSRT_SUCCESS = 0,
    LENSRT_ERROR_INVALID_ARGUMENT, /* a NULL pointer, a count or size out of range */
    LENSRT_ERROR_OUT_OF_MEMORY,
    LENSRT_ERROR_IO,               /* a file could not be read or written */
    LENSRT_ERROR_PARSE,            /* a lens table or phasor file is malformed */
    LENSRT_ERROR_OUT_OF_DOMAIN,    /* outside what the lens was fitted for */
    LENSRT_ERROR_INCOMPATIBLE,     /* phasor sums of a different scene */
    LENSRT_ERROR_UNSUPPORTED,      /* a feature left out of this build */
    LENSRT_ERROR_CANCELLED,        /* the progress callback asked to stop */
    LENSRT_ERROR_NO_DEVICE,        /* no OpenGL 4.3 context could be made (the CPU still works) */
    LENSRT_ERROR_DEVICE            /* the GL device failed (a shader, a buffer) */
};

/* A static string naming the result ("success", "invalid argument", ...). */
LENSRT_API const char *lensrt_result_string(lensrt_result result);

/* ---------------------------------------------------------------- context ----- */

typedef enum lensrt_log_level {
    LENSRT_LOG_ERROR = 0,
    LENSRT_LOG_WARNING = 1,
    LENSRT_LOG_INFO = 2
} lensrt_log_level;

typedef struct lensrt_context_s *lensrt_context;

/* Where the GL device's context comes from (see lensrt_context_gl_info). AUTO tries,
 * in order: the EGL device platform (non-software devices first, as NVIDIA's driver
 * offers), Mesa's surfaceless EGL platform, then GLFW 3.3 with a hidden window (needs an
 * X server, e.g. xvfb-run). Libraries are loaded at run time: a machine without them
 * still runs the CPU path. The context lensrt makes is current only during its calls
 * (the thread's previous EGL or GLFW context is restored after), and lensrt tears down
 * nothing process-wide: EGL displays are never terminated (a display is shared by
 * everyone in the process who asks for the same one; with EGL_KHR_display_reference
 * lensrt takes a counted reference and releases it), GLFW is never terminated, and
 * lensrt's GLFW error callback is installed only while it makes its window (the host's
 * is put back).
 *
 * CALLER uses the caller's own context instead: the EGL context current on the calling
 * thread when the GL device is first used (lensrt_context_gl_info or the first render
 * with LENSRT_DEVICE_GL). It must be desktop OpenGL 4.3 or later (compute shaders; core
 * or compatibility profile), else LENSRT_ERROR_NO_DEVICE says why. The caller keeps that
 * same context current on the calling thread during every call that uses the GL device
 * (lensrt_render_create, _run, _splat_points and _destroy of GL renders); otherwise the
 * call fails with LENSRT_ERROR_DEVICE (and _destroy leaves the render's GL objects in
 * the context). lensrt then never makes a context current, and creates or destroys no
 * display or context; the renders' buffers and programs live in the caller's context,
 * and the GL state a call changes (the current program, the shader storage buffer
 * bindings) is restored before it returns. */
typedef enum lensrt_gl_platform {
    LENSRT_GL_PLATFORM_AUTO = 0,
    LENSRT_GL_PLATFORM_EGL_DEVICE,
    LENSRT_GL_PLATFORM_EGL_SURFACELESS,
    LENSRT_GL_PLATFORM_GLFW,
    LENSRT_GL_PLATFORM_CALLER
} lensrt_gl_platform;

typedef struct lensrt_context_init {
    size_t struct_size;        /* sizeof(lensrt_context_init): LENSRT_CONTEXT_INIT */
    /* Allocator hooks: both or neither (NULL: malloc and free). */
    void *(*alloc_fn)(size_t size, void *user_data);
    void (*free_fn)(void *ptr, void *user_data);
    /* Log hook (NULL: silent). The message is valid during the call only. */
    void (*log_fn)(lensrt_log_level level, const char *message, void *user_data);
    void *user_data;
    /* OpenMP threads for run() (0: the OpenMP default). */
    int32_t threads;
    /* Where a GL device comes from (lensrt_gl_platform), for renders with LENSRT_DEVICE_GL. */
    int32_t gl_platform;
} lensrt_context_init;
/* Keep every *_INIT list in step with its struct's fields (tests/runtime/test_abi.c
 * builds with -Wmissing-field-initializers and compares each with a zeroed struct). */
#define LENSRT_CONTEXT_INIT {sizeof(lensrt_context_init), NULL, NULL, NULL, NULL, 0, 0}

LENSRT_API lensrt_result lensrt_context_create(const lensrt_context_init *init, lensrt_context *out);
/* Destroy every render and lens made with ctx first: their destruction uses the context
 * (its allocator and GL device). */
LENSRT_API void lensrt_context_destroy(lensrt_context ctx);
/* The message of the last failing call made with ctx ("" when none). */
LENSRT_API const char *lensrt_context_last_error(lensrt_context ctx);

/* The context's GL device, made on first use: LENSRT_ERROR_NO_DEVICE (with the reason
 * of every platform tried in the last error) when no OpenGL 4.3 core context can be
 * made, LENSRT_ERROR_UNSUPPORTED when the build has no GL path. Strings stay valid
 * while the context lives. */
typedef struct lensrt_gl_info {
    size_t struct_size;     /* sizeof(lensrt_gl_info): LENSRT_GL_INFO_INIT */
    const char *platform;   /* "egl-device", "egl-surfaceless", "glfw" or "caller" */
    const char *renderer;   /* GL_RENDERER, e.g. "llvmpipe (LLVM 15.0.6, 256 bits)" */
    const char *version;    /* GL_VERSION */
    int32_t software;       /* 1 for a CPU rasteriser (llvmpipe, softpipe, swrast) */
} lensrt_gl_info;
#define LENSRT_GL_INFO_INIT {sizeof(lensrt_gl_info), NULL, NULL, NULL, 0}

LENSRT_API lensrt_result lensrt_context_gl_info(lensrt_context ctx, lensrt_gl_info *out);

/* ------------------------------------------------------------------ lenses ----- */

typedef struct lensrt_lens_s *lensrt_lens;

/* Load a fitted lens from its coefficient table (format `lensfit-poly-table` version 5:
 * fit/lensfit/codegen/table.py; its checksum, the ranges of its values and its probe
 * lines are checked; older versions are refused with a message saying how to upgrade or
 * regenerate the table). */
LENSRT_API lensrt_result lensrt_lens_load(lensrt_context ctx, const char *table_path, lensrt_lens *out);
/* The same from memory; `name` is used in messages. */
LENSRT_API lensrt_result lensrt_lens_load_text(lensrt_context ctx, const char *text, size_t size,
                                    const char *name, lensrt_lens *out);

/* An analytic lens for validation and for scenes without a real lens: the aperture
 * plane, then free space to a sensor `sensor_distance_mm` behind it. With a focal length
 * the aperture holds a perfect thin lens (every path from a light to its geometric image
 * has the same optical path length). With `one_dimensional` the aperture is a line (x)
 * and waves are cylindrical, as in the paper's Algorithm 1; the sensor is then one row. */
typedef struct lensrt_analytic_lens {
    size_t struct_size;        /* sizeof(lensrt_analytic_lens): LENSRT_ANALYTIC_LENS_INIT */
    double focal_length_mm;    /* 0: no lens, free space */
    double sensor_distance_mm; /* aperture plane to sensor plane, > 0 */
    int32_t one_dimensional;
} lensrt_analytic_lens;
#define LENSRT_ANALYTIC_LENS_INIT {sizeof(lensrt_analytic_lens), 0.0, 0.0, 0}

LENSRT_API lensrt_result lensrt_lens_create_analytic(lensrt_context ctx, const lensrt_analytic_lens *desc,
                                          lensrt_lens *out);
/* Frees through the context that created the lens (ctx may be NULL). */
LENSRT_API void lensrt_lens_destroy(lensrt_context ctx, lensrt_lens lens);

typedef struct lensrt_lens_info {
    size_t struct_size;          /* sizeof(lensrt_lens_info): LENSRT_LENS_INFO_INIT */
    const char *name;            /* valid while the lens lives */
    int32_t analytic;            /* 1 for lensrt_lens_create_analytic lenses */
    double focal_length_mm;      /* paraxial EFL (y meridian) */
    double f_number_min;         /* widest f-number the fit covers */
    double stop_radius_max_mm;   /* stop radius the fit covers */
    double wavelength_min_nm, wavelength_max_nm;
    double focus_offset_min_mm, focus_offset_max_mm; /* sensor shift z_S range */
    double field_x, field_y;     /* largest direction cosines of a light */
    double distance_min_mm;      /* closest light (from the first vertex); 0: any */
    double sensor_radius_mm;     /* image circle the fit covers */
    /* How far the polynomials' PSF is from the exactly traced one (table version 3's
     * trust lines): the worst relative L2 distance over the fit's trust table (0.01 is
     * 1%), the PSF error the fit was made for, and which cell was worst (e.g.
     * "f/2 axis 450 nm"; valid while the lens lives). Loading logs them (INFO), and a
     * WARNING when psf_vs_exact > psf_target. Analytic lenses: 0, 0 and "". */
    double psf_vs_exact;
    double psf_target;
    const char *psf_vs_exact_cell;
    /* Ghost tables (issue 13: `ghost` lines, generated/<lens>/ghosts/ghost_<i>_<j>.table):
     * ghost 1, the model surface indices of the first and second reflection (i < j), the
     * file's label (e.g. "4-8"; valid while the lens lives) and the clip pairs of its
     * P_clip system (0..4). A ghost renders as any lens, with its own phasor sums: a
     * light's image with flares is the direct image plus each ghost's (intensities add).
     * Direct tables and analytic lenses: 0, 0, 0, "" and 0. */
    int32_t ghost;
    int32_t ghost_first, ghost_second;
    const char *ghost_label;
    int32_t ghost_clip_pairs;
} lensrt_lens_info;
#define LENSRT_LENS_INFO_INIT {sizeof(lensrt_lens_info), NULL, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, NULL, \
                               0, 0, 0, NULL, 0}

LENSRT_API lensrt_result lensrt_lens_get_info(lensrt_lens lens, lensrt_lens_info *out);

/* Where a light's chief ray (through the stop centre) meets the sensor, in mm on the
 * sensor: the point where the total phase is stationary at the stop centre, found by
 * Newton's method on the polynomials (for analytic lenses, the geometric image). NaN
 * arguments, field angles beyond +-90 deg and negative distances are
 * LENSRT_ERROR_INVALID_ARGUMENT; wavelengths, focus offsets and distances outside the
 * lens's fitted ranges (lensrt_lens_info) LENSRT_ERROR_OUT_OF_DOMAIN. */
typedef struct lensrt_light lensrt_light;
LENSRT_API lensrt_result lensrt_lens_image_point(lensrt_context ctx, lensrt_lens lens, const lensrt_light *light,
                                      double wavelength_nm, double focus_offset_mm, double xy_mm[2]);

/* P_o's inputs (x_O, y_O) for a light (for a renderer's own P_o calls, lensrt_lens_eval):
 * the direction cosines from the first vertex towards the light, (-tan field_x,
 * -tan field_y, 1) normalised, since field angles are the chief ray's (lensrt_light).
 * The one conversion every render and lensrt_lens_image_point use. Field angles that
 * are not finite or not within +-90 deg are LENSRT_ERROR_INVALID_ARGUMENT. */
LENSRT_API lensrt_result lensrt_light_direction_cosines(lensrt_context ctx, const lensrt_light *light, double xy[2]);

/* ------------------------------------------------------- per-ray evaluation ----- */

/* The fitted systems of a lens, for a renderer's own rays (camera rays through the
 * polynomials, as a path tracer does):
 *   P_o (object side): (x_O, y_O, u_O, x_a, y_a, lambda) -> (x_o, y_o, tau_o, phi_o)
 *     x_O, y_O direction cosines from the lens towards the light
 *     (lensrt_light_direction_cosines), u_O = 1 / distance (1/mm, 0: infinity),
 *     x_a, y_a the point on the stop (mm), lambda (nm) -> outer pupil point (mm),
 *     power transmittance, optical path length from the light's reference to the stop
 *     (mm).
 *   P_s (sensor side): (x_S, y_S, z_S, x_a, y_a, lambda) -> (x_i, y_i, tau_i, phi_i)
 *     sensor point (mm), sensor shift (mm), stop point (mm), lambda (nm) -> inner pupil
 *     point (mm), transmittance, optical path length from the stop to the sensor point
 *     (mm). The direction of the ray arriving at (x_S, y_S) is the gradient of phi_i
 *     over (x_S, y_S) (the Jacobian gives it; d phi_i / d z_S is its z cosine, and
 *     minus the gradient over (x_a, y_a) is the direction leaving the stop). Likewise
 *     the gradient of phi_o over (x_a, y_a) is the direction arriving at the stop, and
 *     at u_O = 0 minus its gradient over (x_O, y_O) is where the incoming ray crosses
 *     the plane of the first vertex (mm). tests/runtime/test_lens_eval.py checks these
 *     against exactly traced rays.
 * lensrt_lens_system_info names the inputs and outputs and the domain each input was
 * fitted over; outside it the polynomials extrapolate (nothing is clamped). */
typedef enum lensrt_system_id {
    LENSRT_SYSTEM_OBJECT = 0,   /* P_o */
    LENSRT_SYSTEM_SENSOR = 1,   /* P_s */
    LENSRT_SYSTEM_CLIP = 2      /* a ghost table's P_clip: the ghost side's inputs, outputs
                                   in (x, y) pairs (lensrt_lens_info.ghost_clip_pairs; a lens
                                   without one: LENSRT_ERROR_UNSUPPORTED) */
} lensrt_system_id;

typedef enum lensrt_number_type {
    LENSRT_TYPE_DOUBLE = 0,
    LENSRT_TYPE_FLOAT = 1
} lensrt_number_type;

#define LENSRT_MAX_SYSTEM_INPUTS 8
#define LENSRT_MAX_SYSTEM_OUTPUTS 8

typedef struct lensrt_system_info {
    size_t struct_size;         /* sizeof(lensrt_system_info): LENSRT_SYSTEM_INFO_INIT */
    int32_t n_inputs, n_outputs;
    /* Names as in the table ("x_S", ..., "phi_i"), valid while the lens lives. */
    const char *input_names[LENSRT_MAX_SYSTEM_INPUTS];
    const char *output_names[LENSRT_MAX_SYSTEM_OUTPUTS];
    double input_min[LENSRT_MAX_SYSTEM_INPUTS], input_max[LENSRT_MAX_SYSTEM_INPUTS];
    int32_t n_terms[LENSRT_MAX_SYSTEM_OUTPUTS];
} lensrt_system_info;
#define LENSRT_SYSTEM_INFO_INIT {sizeof(lensrt_system_info), 0, 0, {0}, {0}, {0}, {0}, {0}}

LENSRT_API lensrt_result lensrt_lens_system_info(lensrt_lens lens, int32_t system, lensrt_system_info *out);

typedef struct lensrt_eval_desc {
    size_t struct_size;         /* sizeof(lensrt_eval_desc): LENSRT_EVAL_DESC_INIT */
    int32_t system;             /* lensrt_system_id */
    int32_t type;               /* lensrt_number_type of inputs, outputs and jacobians */
    size_t n_rays;
    /* Raw inputs in the units above, ray-major: inputs[k * n_inputs + i]. */
    const void *inputs;
    /* outputs[k * n_outputs + o] */
    void *outputs;
    /* NULL, or d output / d raw input: jacobians[(k * n_outputs + o) * n_inputs + i] */
    void *jacobians;
} lensrt_eval_desc;
#define LENSRT_EVAL_DESC_INIT {sizeof(lensrt_eval_desc), 0, 0, 0, NULL, NULL, NULL}

/* Evaluate a fitted system for a batch of rays on the calling thread (no OpenMP, no
 * allocation through the context for batches of any size). A lens may be evaluated
 * from any number of threads at once. `ctx` receives the error message (NULL: none is
 * recorded; use one context per thread if messages matter). Analytic lenses have no
 * fitted systems: LENSRT_ERROR_UNSUPPORTED. Compiled-in lenses (lensrt_lens_load_compiled)
 * evaluate the values of batches of fewer than 32 rays through their generated Horner
 * code (about 10x faster for one ray; the table is faster per ray for long batches; the
 * two agree within rounding); Jacobians always come from the coefficient table. Float
 * batches from the table are summed in double (float only in memory). An
 * input that is not finite, or a wavelength <= 0, refuses the whole batch before anything
 * is written (LENSRT_ERROR_INVALID_ARGUMENT, the message naming the ray and the input).
 * Finite inputs far outside the fitted domain may overflow the polynomials: a batch with
 * any output or Jacobian entry that is not finite fails as a whole with
 * LENSRT_ERROR_OUT_OF_DOMAIN, its outputs and Jacobians zeroed, the message naming the
 * ray, the output and the input farthest outside its range (no NaN or inf is returned).
 * Batches of 32 rays or more run at full speed; about 30 KB of stack. */
LENSRT_API lensrt_result lensrt_lens_eval(lensrt_context ctx, lensrt_lens lens, const lensrt_eval_desc *desc);

/* ------------------------------------------------------- compiled-in lenses ----- */

/* A lens linked into the program: what `lensrt_add_lens(<target> <lens folder>)` (CMake,
 * cmake/lensrt_add_lens.cmake) generates and compiles into the caller's target from
 * generated/<lens>/: the coefficient table embedded as text, and the generated Horner
 * evaluators of both systems in double and float (raw inputs, as lensrt_lens_eval). */
typedef void (*lensrt_horner_d)(const double *in, double *out);
typedef void (*lensrt_horner_f)(const float *in, float *out);

typedef struct lensrt_compiled_lens {
    size_t struct_size;         /* sizeof(lensrt_compiled_lens) */
    const char *name;           /* "0001-angenieux-double-gauss" */
    const char *table_text;     /* the lens's coefficient table (format version 5) */
    size_t table_size;          /* bytes of table_text */
    lensrt_horner_d object_d, sensor_d; /* P_o and P_s, double */
    lensrt_horner_f object_f, sensor_f; /* the same in float */
} lensrt_compiled_lens;

/* Make a lens from a compiled-in one (nothing is read from files). Renders from it equal
 * renders from lensrt_lens_load of the same table bit for bit. `compiled` must outlive
 * the lens. */
LENSRT_API lensrt_result lensrt_lens_load_compiled(lensrt_context ctx, const lensrt_compiled_lens *compiled,
                                        lensrt_lens *out);

/* ----------------------------------------------------------------- renders ----- */

typedef enum lensrt_sampler {
    LENSRT_SAMPLER_DEFAULT = 0,   /* SOBOL; RANDOM with the unbiased estimator */
    LENSRT_SAMPLER_RANDOM,        /* independent uniform points */
    LENSRT_SAMPLER_STRATIFIED,    /* jittered grid per pass */
    LENSRT_SAMPLER_SOBOL          /* (0,2)-sequence with a random shift per seed */
} lensrt_sampler;

typedef enum lensrt_estimator {
    LENSRT_ESTIMATOR_DEFAULT = 0, /* LENSRT_ESTIMATOR_PAPER */
    LENSRT_ESTIMATOR_PAPER,       /* |sum X|^2 / N^2: biased by variance / N */
    LENSRT_ESTIMATOR_UNBIASED     /* (|sum X|^2 - sum |X|^2) / (N (N - 1)); needs
                                     independent samples (random sampler) */
} lensrt_estimator;

typedef enum lensrt_precision {
    LENSRT_PRECISION_DEFAULT = 0, /* phase reduced in double, float splat kernel */
    LENSRT_PRECISION_DOUBLE,      /* everything in double, no pruning (reference) */
    LENSRT_PRECISION_NAIVE_FLOAT  /* total OPL in float, no reduction (to show why not) */
} lensrt_precision;

typedef enum lensrt_device {
    LENSRT_DEVICE_CPU = 0,        /* OpenMP threads, SIMD splat kernel */
    LENSRT_DEVICE_GL              /* OpenGL 4.3 compute shaders; the same samples and sums */
} lensrt_device;

typedef enum lensrt_pixel_filter {
    LENSRT_PIXEL_FILTER_BOX = 0,  /* the pixel's mean intensity over its area (default) */
    LENSRT_PIXEL_FILTER_POINT     /* the intensity at the pixel's centre (before 0.8.0) */
} lensrt_pixel_filter;
#define LENSRT_MAX_PIXEL_SAMPLES 16     /* sub-pixel samples per axis (box filter) */

typedef enum lensrt_aperture_shape {
    LENSRT_APERTURE_CIRCLE = 0,
    LENSRT_APERTURE_BLADES,       /* a regular polygon of `blades`, optionally curved */
    LENSRT_APERTURE_SLIT          /* one slit, or two with a separation (x only) */
} lensrt_aperture_shape;

/* Embedded in lensrt_render_desc: fixed layout (see the ABI rules). */
typedef struct lensrt_aperture {
    int32_t shape;           /* lensrt_aperture_shape */
    double radius_mm;        /* stop radius; 0: from f_number */
    double f_number;         /* used when radius_mm is 0; 0: the lens's widest */
    int32_t blades;          /* LENSRT_APERTURE_BLADES: 3 .. LENSRT_MAX_BLADES */
    double blade_curvature;  /* 0 straight blades, 1 blades on the circle */
    double rotation_deg;     /* polygon rotation */
    double slit_width_mm;    /* LENSRT_APERTURE_SLIT: width in x */
    double slit_separation_mm; /* centre-to-centre of a double slit; 0: one slit */
} lensrt_aperture;

/* Embedded in lensrt_render_desc: fixed layout (see the ABI rules). */
typedef struct lensrt_sensor {
    int32_t width, height;      /* pixels, 1 .. LENSRT_MAX_RESOLUTION (height 1 for one-dimensional lenses) */
    double width_mm, height_mm; /* size of the pixel grid; height 0: square pixels */
    double center_x_mm, center_y_mm; /* centre of the window on the sensor */
    double focus_offset_mm;     /* z_S: sensor shift, + away from the lens */
} lensrt_sensor;

/* A point light. Field angles follow the lens designers' convention (Zemax, Code V;
 * docs/conventions.md): the light's chief ray enters along (tan field_x,
 * tan field_y, 1), z towards the sensor, so field_y_deg > 0 is a ray rising towards the
 * lens (dy/dz > 0) from a light below the axis, imaged at sensor y > 0 (about
 * f tan field_y). lensrt_light_direction_cosines gives P_o's (x_O, y_O). */
struct lensrt_light {
    size_t struct_size;              /* sizeof(lensrt_light): LENSRT_LIGHT_INIT */
    double field_x_deg, field_y_deg; /* the chief ray's field angles (above), degrees */
    double distance_mm;              /* from the first vertex; 0: infinity */
    double intensity;                /* 0: 1. The light's irradiance on the plane of
                                        the first vertex (z = 0), at the vertex */
};
#define LENSRT_LIGHT_INIT {sizeof(lensrt_light), 0.0, 0.0, 0.0, 0.0}

typedef struct lensrt_render_desc {
    size_t struct_size;           /* sizeof(lensrt_render_desc): LENSRT_RENDER_DESC_INIT */
    lensrt_lens lens;
    lensrt_sensor sensor;
    lensrt_aperture aperture;
    const lensrt_light *lights;  /* copied; NULL with n_lights 0: one light on the axis at infinity */
    int32_t n_lights;            /* 0 .. LENSRT_MAX_LIGHTS */
    const double *wavelengths_nm; /* copied; NULL: n_wavelengths uniform over the lens's range */
    int32_t n_wavelengths;        /* 0: 16; at most LENSRT_MAX_WAVELENGTHS */
    int32_t sampler;              /* lensrt_sampler */
    int32_t estimator;            /* lensrt_estimator */
    int32_t precision;            /* lensrt_precision */
    uint64_t seed;
    double phase_tolerance_waves; /* largest phase the pruned per-pixel terms may drop; 0: 3e-3 */
    int32_t device;               /* lensrt_device: where run() splats; GL takes precision DEFAULT or NAIVE_FLOAT */
    /* Since 0.8.0 (issue 26): what a pixel's value is. BOX (0, the default, also for
     * callers built before 0.8.0): the mean of the intensity over the pixel's area, by
     * the midpoint rule on pixel_samples_x x pixel_samples_y sub-pixel centres per pixel
     * (intensities averaged, never the sub-pixels' fields); 0 on an axis: chosen so that
     * the rendered power of any feature does not depend on its sub-pixel position
     * (README "The model"), 1 .. LENSRT_MAX_PIXEL_SAMPLES. POINT: the intensity at the
     * pixel's centre (lensrt before 0.8.0; the samples must be 0 or 1). One-dimensional
     * lenses have one row: pixel_samples_y must be 0 or 1. */
    int32_t pixel_filter;         /* lensrt_pixel_filter */
    int32_t pixel_samples_x, pixel_samples_y;
} lensrt_render_desc;
#define LENSRT_RENDER_DESC_INIT {sizeof(lensrt_render_desc), NULL, {0, 0, 0, 0, 0, 0, 0}, \
                                 {0, 0, 0, 0, 0, 0, 0, 0}, NULL, 0, NULL, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0}

typedef struct lensrt_render_s *lensrt_render;

/* Check the scene against the lens's fitted domain and allocate the phasor sums.
 * A ghost table (lensrt_lens_info.ghost) renders as any lens, its P_clip tests applied
 * to every sample (side P_o) or splat (side P_s): a pair x_h, y_h passes when
 * x^2 + y^2 <= 1, a stop crossing x_s, y_s (mm) when it lies within the render's stop
 * radius. A ghost with stop crossings needs LENSRT_APERTURE_CIRCLE (else
 * LENSRT_ERROR_UNSUPPORTED naming the table and the ghost). */
LENSRT_API lensrt_result lensrt_render_create(lensrt_context ctx, const lensrt_render_desc *desc,
                                   lensrt_render *out);
LENSRT_API void lensrt_render_destroy(lensrt_render render);

/* Called after each wavelength of each pass (16384 samples per wavelength) with the
 * fraction done and an estimate of seconds left; return non-zero to stop: run() then
 * finishes the current pass and returns LENSRT_ERROR_CANCELLED (the sums keep every
 * completed pass, so every wavelength always holds the same samples). */
typedef int (*lensrt_progress_fn)(double fraction, double eta_seconds, void *user_data);

/* Add `samples_per_wavelength` aperture samples for every wavelength, continuing the
 * sample sequence where the sums left off: two runs draw the same samples as one longer
 * run and give the same sums bit for bit, for any counts, on either device, and so do
 * tile sessions (since 0.10.0; before, only when the first count was a multiple of 256).
 * Samples are summed in blocks of 256 and each block is added to the phasor sums on its
 * own; a run that ends inside a block keeps a copy of the sums from before that block
 * (memory as large as the sums, allocated then and kept with the render) and the next
 * run or tile session puts them back and draws the whole block again (at most 255
 * samples repeated). Reading the results in between (image, rgb, the writers, save)
 * changes nothing. What else changes the sums (load, merge, splat_points, an integral)
 * forgets that copy: a run after a load or merge that ended inside a block starts its
 * blocks there, equal to one run up to rounding (tests/runtime/test_robust.c,
 * test_tiles.c, test_gl.py). */
LENSRT_API lensrt_result lensrt_render_run(lensrt_render render, uint64_t samples_per_wavelength,
                                lensrt_progress_fn progress, void *user_data);

/* Splat caller-chosen aperture points (x, y pairs in mm on the stop, uniform density over
 * the aperture's bounding disc) for wavelength index `wavelength`; points outside the
 * aperture shape, however far, count as samples with zero contribution; points that are
 * not finite are refused (LENSRT_ERROR_INVALID_ARGUMENT). */
LENSRT_API lensrt_result lensrt_render_splat_points(lensrt_render render, int wavelength,
                                         const double *xy_mm, size_t n_points);

/* The deterministic aperture integrator (since 0.4.0), beside Monte Carlo's run(): the
 * aperture (circle, straight or curved blades, slits) is meshed into 6 x rings^2
 * triangles (blades x rings^2 for blades) whose vertices lie on its boundary; on each,
 * the phase and the log amplitude are interpolated linearly and exp(i phase) integrated
 * in closed form, so that a triangle may span many waves of tilt and only the phase's
 * curvature limits its size (the error falls as 1 / rings^2). Clips that depend on the
 * light or the pixel (outer and inner pupil, a ghost's P_clip) cut the triangles along
 * their interpolated boundary. The integrand is the one run() samples, pixel for pixel.
 *
 * The sums then hold the field of this mesh, and image(), rgb() and the writers show
 * it; run(), splat_points(), tiles and save/load/merge refuse such a render. A later
 * call with more rings replaces it. With error_estimate non-NULL (2 rings at least),
 * meshes of rings / 2 and rings / 4 (or the previous call's two, when it had exactly
 * half the rings: a doubling costs one new mesh) give *error_estimate, the image's
 * relative L2 error over every pixel and wavelength: the difference of the images of
 * rings and rings / 2 divided by 2^p - 1, with 2^p the ratio of the two differences
 * (taken within [4, 16]; 4 without a quarter mesh). Measured within 1.0-1.55 times the
 * true error on lens PSFs and ghosts, conservative (up to 7.5 times) on a clean defocus
 * (runtime/README.md). Every pixel's field depends on the pixel alone: the result does
 * not depend on the threads. CPU device only: the GL device
 * returns LENSRT_ERROR_UNSUPPORTED with a message, never a silent fallback; so do
 * one-dimensional lenses, precision NAIVE_FLOAT and the unbiased estimator. */
#define LENSRT_MAX_RINGS 4096
LENSRT_API lensrt_result lensrt_render_integrate(lensrt_render render, int32_t rings, double *error_estimate,
                                      lensrt_progress_fn progress, void *user_data);

/* The Fourier integrator (since 0.6.0), beside run() and integrate(): the field of a
 * whole window at once. The aperture's integral is a Gauss-Legendre product rule of
 * `nodes` x `nodes` points on each fan sector (circle, straight or curved blades; a slit
 * is a rectangle), following the true boundary, so that it converges spectrally once the
 * nodes resolve the waves of phase across the aperture (about 1.4 per wave). Around the
 * centre of a tile of pixels the phase is linear in the pixel's position plus a small
 * rest: the linear part makes every pixel's sum over the nodes one type-1 non-uniform
 * FFT for the whole tile; the rest and the amplitude are interpolated across the tile
 * on Chebyshev nodes of degree 2 to 4 (a tile the interpolation cannot follow to 1e-3
 * is split). The cost is (nodes + pixels log pixels) per tile and wavelength, instead of
 * their product; the integrand is the one run() samples (P_s terms pruned only below
 * 1e-3 / (2 pi x 25) waves), with the same units.
 *
 * nodes 0: chosen from the phase (since a pilot rule measures its largest change across
 * the aperture over the window's corner pixels: 1.4 nodes per wave, 4 more), refused
 * (LENSRT_ERROR_UNSUPPORTED) where that rule would hold more than 64 nodes per pixel of
 * the window: the phase swings so far (a defocused ghost) that the cells integrator is
 * the cheaper there. The nodes chosen are the stats' fourier_nodes.
 *
 * With error_estimate non-NULL a rule of ceil(1.25 nodes) nodes (and tolerances a tenth)
 * is integrated as well and *error_estimate is the relative L2 distance of this image
 * from that one over every pixel and wavelength: the error of the image the sums hold
 * (the `nodes` one), the finer image's own error being far smaller once the rule
 * converges (measured within 0.8-1.15 times the true error on lens PSFs from 1e-4 to
 * 30%; runtime/bench/fourier_bench.py). Where the rule is too coarse to resolve the
 * phase at all both images are wrong and the estimate only says so (30% or more). A
 * call with the previous call's finer nodes reuses that field (a
 * refinement costs one new rule). The sums hold the field; image(), rgb() and the writers
 * show it; run(), splat_points(), tiles and save/load/merge refuse such a render.
 *
 * Clips that cut the aperture (the outer or inner pupil vignetting some paths, a ghost's
 * P_clip) are not resolved: such a render is LENSRT_ERROR_UNSUPPORTED with a message
 * naming the clip, the point and the wavelength, and lensrt_render_integrate (cells)
 * serves it. So are the GL device, one-dimensional lenses, precision NAIVE_FLOAT and
 * the unbiased estimator. Each wavelength is made by one thread: the result does not
 * depend on the threads. */
#define LENSRT_MAX_FOURIER_NODES 4096
#define LENSRT_FOURIER_FINER 1.25 /* the estimate's finer rule: ceil(1.25 nodes) per side */
LENSRT_API lensrt_result lensrt_render_integrate_fourier(lensrt_render render, int32_t nodes,
                                                         double *error_estimate, lensrt_progress_fn progress,
                                                         void *user_data);

/* Since 0.7.0: the nodes per side that resolve the render's integrand for an image whose
 * relative L2 error should be `target` (0: the rule nodes 0 takes, aiming at a few 1e-5 to
 * 1e-4; 1% or more: 1.33 instead of 1.4 nodes per wave, 2 instead of 4 more, measured to
 * give 7.5e-5 to 5e-3 on lens PSFs from f/2 to f/32 and defocused perfect lenses; in
 * between in proportion to log10 target). The first rule of a refinement to a target:
 * lensrt_render_integrate_fourier(render, *nodes, &estimate, ...), then 1.25 times the
 * nodes while the estimate is above it. The same pilot rule and the same refusals as
 * nodes 0 (LENSRT_ERROR_UNSUPPORTED beyond 64 nodes per pixel, a clip, the GL device);
 * the sums are untouched, the pilot's seconds count in the stats. */
LENSRT_API lensrt_result lensrt_render_fourier_nodes(lensrt_render render, double target, int32_t *nodes);

/* Since 0.10.0: the geometric footprint of the render's lights on the sensor, for deciding
 * whether an image (a ghost's) can reach the window at all before integrating it:
 * box_mm = (x_min, x_max, y_min, y_max) in mm on the sensor (the window's coordinates) of
 * the points where rays through the aperture land, over every light and wavelength. A
 * ray's landing point is the sensor point where the total phase (P_o + P_s) is
 * stationary at its stop point, found by Newton's method, for the stop centre, 64 points
 * on the aperture's rim and the points of a 9 x 9 grid inside it; rays that a clip stops
 * (the outer or inner pupil, a ghost's P_clip) are left out. No ray passes: x_min > x_max
 * (+inf, -inf, +inf, -inf). The image is no larger than this box plus diffraction: a
 * defocused edge's diffraction falls to about 1e-4 of the image's level within 30
 * wavelengths x the f-number (lensrt-psf skips a ghost whose box, widened by that much,
 * misses the window). The sums are untouched. LENSRT_ERROR_OUT_OF_DOMAIN when a ray's
 * landing point is not found (the polynomials do not say: decide by integrating);
 * LENSRT_ERROR_UNSUPPORTED for analytic and one-dimensional lenses. */
LENSRT_API lensrt_result lensrt_render_footprint(lensrt_render render, double box_mm[4]);

/* Host-scheduled tiles: the same samples as lensrt_render_run(render, samples_per_wavelength,
 * NULL, NULL), rendered one rectangle of the window at a time on threads the caller
 * schedules (TBB, its own pool). The sums after tiles_end equal those of that run() bit
 * for bit, whatever the rectangles, their order and the threads, and a session continues
 * a run that ended inside a block as run() does. CPU device only.
 *
 *   lensrt_render_tiles_begin(render, N);             caller's thread
 *   lensrt_render_tile(render, x0, y0, w, h);  ...    any threads, disjoint rectangles
 *   lensrt_render_tiles_end(render);                  caller's thread, after every tile returned
 *
 * tiles_begin fixes the next sample range [S, S + N) per wavelength, S being the samples
 * already in the sums (as run() would draw it). It keeps a copy of the sums, so that a
 * failed session leaves them as they were. LENSRT_ERROR_UNSUPPORTED (with a message) on
 * the GL device; LENSRT_ERROR_INVALID_ARGUMENT when N is not 1..2^40 or a session is
 * already open. Until tiles_end, run(), splat_points(), image(), rgb(), the image writers
 * and save/load/merge refuse with LENSRT_ERROR_INVALID_ARGUMENT. */
LENSRT_API lensrt_result lensrt_render_tiles_begin(lensrt_render render, uint64_t samples_per_wavelength);

/* Since 0.4.0: a tile session of the cells integrator instead of samples: the same
 * tiles and tiles_end, and after tiles_end the sums equal those of
 * lensrt_render_integrate(render, rings, estimate ? &e : NULL, ...) on a render with no
 * earlier integral, bit for bit, whatever the rectangles, their order and the threads;
 * the estimate (estimate non-zero) is then the stats' cells_error_estimate. Each tile
 * prepares the meshes' vertices for itself (a few milliseconds per wavelength at 32
 * rings), so tiles of a few thousand pixels or more keep that small. The checks and
 * refusals of lensrt_render_integrate apply. */
LENSRT_API lensrt_result lensrt_render_tiles_begin_cells(lensrt_render render, int32_t rings, int32_t estimate);

/* Since 0.6.0: a tile session of the Fourier integrator: the same tiles and tiles_end,
 * and after tiles_end the sums equal those of lensrt_render_integrate_fourier(render,
 * nodes, estimate ? &e : NULL, ...) on a render with no earlier integral, bit for bit,
 * whatever the rectangles, their order and the threads (nodes 0 is chosen here, on the
 * caller's thread, as that call chooses it). A host tile renders every tile of the
 * window's own decomposition that meets its rectangle, whole, and keeps its pixels: host
 * tiles smaller than the window's tiles (the whole window, for most PSFs) repeat their
 * work, so use as many host tiles as threads. The checks and refusals of
 * lensrt_render_integrate_fourier apply; a tile the integrator refuses (a clip) fails
 * with its message. */
LENSRT_API lensrt_result lensrt_render_tiles_begin_fourier(lensrt_render render, int32_t nodes, int32_t estimate);

/* Render pixels x0 .. x0 + width - 1 of rows y0 .. y0 + height - 1 (row 0 at the top) for
 * every light and wavelength and the session's whole sample range, on the calling thread
 * alone (no OpenMP), adding to those pixels' sums. Any number of threads may call it at
 * once, for disjoint rectangles; every pixel must be covered exactly once before
 * tiles_end. A rectangle outside the window or one that touches an already covered pixel
 * renders nothing and fails (LENSRT_ERROR_INVALID_ARGUMENT), as do calls outside a session.
 *
 * Thread model: a tile reads the render's prepared scene and writes only its own pixels'
 * sums; coverage counts, statistics, the first failure and the session's shared samples
 * are kept with atomic operations. It never writes the context's last error (other tiles
 * may be running): the result code says what failed, and tiles_end reports the first
 * failure with its message. Each pass's samples of each wavelength are drawn and
 * prepared once per session, by the tiles that reach them first, each taking chunks of
 * 512 samples no other tile has taken; a tile that finds the last chunks taken (or the
 * slot being allocated) waits for them by spinning (a fraction of a millisecond, longer
 * only if the thread preparing one is descheduled; the thread preparing a chunk never
 * waits). The shared samples are kept
 * until tiles_end, at most 512 MB per session (about 13 MB per pass and wavelength for
 * lens 0001 in float); beyond that, tiles prepare the samples themselves (same bits, more
 * time: runtime/README.md gives the measured costs) in one pass's buffers (up to 16384
 * samples per wavelength). Memory comes from the context's allocator hooks, which must
 * therefore be thread-safe (malloc is); a tile uses about 170 KB of the calling thread's
 * stack (about 450 KB for a ghost table whose P_clip takes P_s's inputs). */
LENSRT_API lensrt_result lensrt_render_tile(lensrt_render render, int x0, int y0, int width, int height);

/* End the session on the caller's thread once every tile call has returned: checks that
 * every pixel was covered exactly once (else LENSRT_ERROR_INVALID_ARGUMENT naming the
 * first pixel, in row-major order, that was not covered or was covered more than once)
 * and that no tile failed (else that failure's result and message); on failure the sums
 * are put back as they were before tiles_begin. On success the session's samples, splats,
 * statistics and wall time (tiles_begin to tiles_end) are added as run() would. Either way
 * the session's shared samples are freed. */
LENSRT_API lensrt_result lensrt_render_tiles_end(lensrt_render render);

typedef struct lensrt_render_stats {
    size_t struct_size;               /* sizeof(lensrt_render_stats): LENSRT_RENDER_STATS_INIT */
    int32_t width, height, n_wavelengths, n_lights;
    uint64_t samples_per_wavelength;  /* the sample count N of every wavelength */
    uint64_t splats;                  /* aperture samples x pixels, over all passes */
    double seconds;                   /* wall time spent in run() and splat_points() */
    double splats_per_second;
    double stop_radius_mm, f_number;
    /* What the per-pixel pruning left, averaged over pixels and wavelengths of the last
     * pass (fitted lenses): phase terms per splat, and the fractions of pixels that
     * needed the inner-pupil clip, a varying transmittance, or were fully clipped. */
    double phase_terms, clip_fraction, tau_fraction, dark_fraction;
    /* Since 0.4.0: the rings of the cells integral the sums hold (0: Monte Carlo) and its
     * error estimate (-1: none asked for) */
    int32_t cells_rings;
    double cells_error_estimate;
    /* Since 0.6.0: the nodes per side of the Fourier integral the sums hold (0: none; its
     * error estimate is then cells_error_estimate) */
    int32_t fourier_nodes;
    /* Since 0.8.0: the pixel filter (lensrt_pixel_filter) and the sub-pixel samples per
     * pixel and axis the render uses (1 x 1 for POINT) */
    int32_t pixel_filter, pixel_samples_x, pixel_samples_y;
} lensrt_render_stats;
#define LENSRT_RENDER_STATS_INIT {sizeof(lensrt_render_stats), 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0}

LENSRT_API lensrt_result lensrt_render_get_stats(lensrt_render render, lensrt_render_stats *out);
/* The wavelengths in use (n_wavelengths of them). */
LENSRT_API const double *lensrt_render_wavelengths(lensrt_render render);

/* Intensity per wavelength, lights added: out[(w * height + y) * width + x], count =
 * n_wavelengths * width * height. Units: irradiance on the sensor relative to the
 * light's irradiance on the first vertex plane (its intensity), so the sum over pixels
 * times the pixel area is the power the lens passes from a unit light: the stop's area
 * times the front group's flux per unit stop area, times transmittance. For an analytic
 * lens the stop is that plane. Row 0 is the top of the image (+y).
 * A pixel that is not a finite float is LENSRT_ERROR_OUT_OF_DOMAIN with a message naming
 * the pixel and wavelength (lensrt_render_rgb and the image writers likewise). */
LENSRT_API lensrt_result lensrt_render_image(lensrt_render render, float *out, size_t count);
/* Linear sRGB (D65 white) from the spectral image through the CIE 1931 2-degree
 * observer: out[(y * width + x) * 3 + c], count = 3 * width * height. */
LENSRT_API lensrt_result lensrt_render_rgb(lensrt_render render, float *out, size_t count);
/* The same colour conversion for a spectral image the caller holds (since 0.9.0; a PSF
 * bank's node whose channels are renders of their own): spectral[w * n_pixels + p] at
 * n_wavelengths strictly increasing wavelengths (each weighted by the span to the
 * midpoints between its neighbours, as lensrt_render_rgb does), rgb[p * 3 + c]. */
LENSRT_API lensrt_result lensrt_spectrum_rgb(lensrt_context ctx, int n_wavelengths, const double *wavelengths_nm,
                                             const float *spectral, size_t n_pixels, float *rgb);

/* Phasor sums: save, load (replace), merge (add; the scene must match and the sample
 * ranges must not overlap). Files are written atomically (format: io/phasor_file.c).
 * Only Monte Carlo sums are saved (run(), splat_points(), tiles; a cells or Fourier
 * render is refused).
 *
 * What a saved sum is, and its phase reference. For light l, wavelength lambda and grid
 * point s (the pixel centre; a box filter's sub-pixel points), the file holds the complex
 * sum over the samples a_j of the stop, S(s) = sum_j A_j K(s) exp(+i 2 pi P_j(s) / lambda),
 * with A_j the sample's amplitude (sqrt of intensity x tau_o x flux x tau_i), K(s) the
 * pixel's Huygens amplitude (README "The model"); the field is U(s) = measure / N x S(s)
 * and the paper estimator's intensity |U|^2. The phase is in radians of exp(+i k OPL):
 * a longer path turns it counter-clockwise. P_j(s), in mm, is:
 *   - fitted lenses (tables), precision DEFAULT or DOUBLE, either device:
 *     phi_o(a_j) + phi_i(a_j, s) - phi_i(0, s). phi_o is the table's P_o phase (the
 *     optical path from the light to the stop point minus d_O, the light's distance from
 *     the first vertex; at infinity, from the plane wave through that vertex), kept whole;
 *     phi_i(0, s) is the rear group's path from the stop centre to s. So each grid point's
 *     phase is referenced to the stop-centre ray's rear path to that point: arg S(s)
 *     equals the phase of the total path relative to the stop-centre path
 *     (phi_o(0) + phi_i(0, s)), plus 2 pi phi_o(0) / lambda, which is the same for every
 *     grid point of a light and wavelength. Terms the pixel set-up prunes change it by at
 *     most phase_tolerance_waves (none in DOUBLE);
 *   - fitted lenses in precision NAIVE_FLOAT: the whole path, phi_o + d_O + phi_i (no
 *     reference);
 *   - analytic lenses: the whole free-space path, incoming wave + |s - a_j| (no per-pixel
 *     reference): the incoming wave is -(x, y) . the light's direction cosines at infinity,
 *     |light - a_j| - d_O for a near light, or for a perfect lens -|image point - a_j| (its
 *     sphere converging on the light's image, so a pixel at focus on the image point has
 *     phase 0); NAIVE_FLOAT adds the light's distance.
 * Checked against quadratures of the integrand (lens 0001 at f/8, 550 nm, 9 x 9 pixels of
 * 2 um: within 1.2 mrad with the reference, up to 2.1 rad without; a perfect lens 2 um
 * behind focus: arg S at the image point equals k (|s - a| - |I - a|) integrated).
 * Two files of the same scene (the scene hash: lens, lights, wavelengths, window,
 * aperture, precision, phase tolerance) share this reference, so merging (adding the
 * sums and sample counts, N the total) is coherent. Sums of different lights, different
 * ghost paths or another lens must not be added coherently at all (their intensities
 * add): lensrt never does, and a reader that wants the absolute phase of a fitted lens's
 * sum must multiply S(s) by
 * exp(+i 2 pi phi_i(0, s) / lambda) itself (lensrt_lens_eval of P_s at the stop centre). */
LENSRT_API lensrt_result lensrt_render_save(lensrt_render render, const char *path);
LENSRT_API lensrt_result lensrt_render_load(lensrt_render render, const char *path);
LENSRT_API lensrt_result lensrt_render_merge(lensrt_render render, const char *path);

/* Image files, written atomically (temporary file, then rename). The EXR holds one
 * channel per wavelength (spectral layout, `S0.<lambda>nm`), an RGB preview and the lens
 * and render metadata; the PNG is an 8-bit sRGB preview with a logarithmic tone map
 * over `decades` of intensity below the peak (0: 5). */
LENSRT_API lensrt_result lensrt_render_write_exr(lensrt_render render, const char *path);
LENSRT_API lensrt_result lensrt_render_write_png(lensrt_render render, const char *path, double decades);

/* How lensrt_render_write_exr_with writes (since 0.5.0). Versioned: start from
 * LENSRT_EXR_OPTIONS_INIT; zero means the defaults, lensrt_render_write_exr's file. */
typedef struct lensrt_exr_options {
    size_t struct_size;      /* sizeof(lensrt_exr_options): LENSRT_EXR_OPTIONS_INIT */
    /* 1: leave out what differs between two runs of the same render (the attributes
     * lensrt/seconds, lensrt/splatsPerSecond and lensrt/lensFile), so that the same
     * render gives the same bytes (a PSF bank's nodes, whose index holds their CRC-32);
     * 0: write them. Other values are refused. */
    int32_t reproducible;
} lensrt_exr_options;
#define LENSRT_EXR_OPTIONS_INIT {sizeof(lensrt_exr_options), 0}

/* lensrt_render_write_exr with options (NULL: the same as lensrt_render_write_exr). */
LENSRT_API lensrt_result lensrt_render_write_exr_with(lensrt_render render, const char *path,
                                                      const lensrt_exr_options *options);

/* Images that add: a light's direct image plus its ghosts' (each ghost its own render,
 * its own phasor sums; intensities add, never phasors). The sum of the renders' images
 * (lensrt_render_image each, summed in double), as an image, an EXR (the first render's
 * metadata) or a PNG. The renders must share the window (resolution, pitch, centre) and
 * the wavelengths: otherwise LENSRT_ERROR_INCOMPATIBLE naming the first that differs
 * (its lens file) and how. One render gives exactly its own image. */
LENSRT_API lensrt_result lensrt_renders_image(const lensrt_render *renders, int n_renders, float *out, size_t count);
LENSRT_API lensrt_result lensrt_renders_write_exr(const lensrt_render *renders, int n_renders, const char *path);
LENSRT_API lensrt_result lensrt_renders_write_png(const lensrt_render *renders, int n_renders, const char *path,
                                                 double decades);

/* One layer of a layered EXR (lensrt_layers_write_exr): a name and the renders whose
 * images add into it (as lensrt_renders_image). Versioned: start from
 * LENSRT_EXR_LAYER_INIT. */
typedef struct lensrt_exr_layer {
    size_t struct_size;
    const char *name;              /* 1 to LENSRT_MAX_LAYER_NAME characters of [A-Za-z0-9_-],
                                      unique in the file; not S0-S3, M00-M33 or T (the
                                      spectral layout's channel groups) */
    const lensrt_render *renders;  /* n_renders >= 1 renders of the same window and
                                      wavelengths as every other layer's */
    int32_t n_renders;
} lensrt_exr_layer;
#define LENSRT_EXR_LAYER_INIT {sizeof(lensrt_exr_layer), NULL, NULL, 0}

/* One EXR holding layers and their sum (e.g. a light's direct image and its flare):
 *   - the unprefixed channels (`S0.<lambda>nm`, R, G, B) hold the sum of every render of
 *     every layer, exactly what lensrt_renders_write_exr of all of them writes: every
 *     spectral-EXR reader and viewer sees the whole image by default;
 *   - each layer's channels carry its name as OpenEXR layer prefix, `<name>.S0.<lambda>nm`,
 *     `<name>.R`, `<name>.G`, `<name>.B`, holding lensrt_renders_image of its renders
 *     (one render: lensrt_render_image bit for bit).
 * Metadata from the first layer's first render, and "lensrt/layers" saying which lens
 * tables each layer adds. Written atomically. A bad or repeated name, a render in two
 * layers (the sum would count it twice) or renders of another window or wavelengths:
 * LENSRT_ERROR_INVALID_ARGUMENT or _INCOMPATIBLE with a message naming the path and the
 * layer; no file is written then. NULL layers, n_layers < 1, or a first layer without a
 * struct_size or a first render: LENSRT_ERROR_INVALID_ARGUMENT with no context to hold a
 * message (the messages go to the first render's context). */
LENSRT_API lensrt_result lensrt_layers_write_exr(const lensrt_exr_layer *layers, int n_layers, const char *path);
/* The same with options (since 0.5.0; NULL: as lensrt_layers_write_exr): reproducible
 * leaves out what differs between two runs, as lensrt_render_write_exr_with does. */
LENSRT_API lensrt_result lensrt_layers_write_exr_with(const lensrt_exr_layer *layers, int n_layers, const char *path,
                                                      const lensrt_exr_options *options);

/* ------------------------------------------------------------- PSF banks ----- */

/* A PSF bank (since 0.5.0): a lens's point spread functions rendered ahead of time on a
 * grid of f-numbers, focus offsets, light distances and field angles, for renderers
 * that look PSFs up instead of integrating them. A bank is a folder:
 *
 *   bank.index            text, below
 *   nodes/<name>.exr      one EXR per node, written by lensrt_render_write_exr_with
 *                         (reproducible): spectral channels S0.<lambda>nm (FLOAT) at the
 *                         index's wavelengths, plus R, G, B (ignored here)
 *
 * The index (version 1): one item per line, tokens separated by single spaces, numbers
 * as "C"-locale decimal text (Python's repr(float) writes them), LF line ends, no blank
 * lines, the keys in this order:
 *
 *   lensrt-bank 1
 *   lens <name, printable ASCII without spaces>
 *   table_crc32 <8 lowercase hex digits: CRC-32 of the lens table file's bytes>
 *   width <pixels>
 *   height <pixels>
 *   pixel_mm <pitch x> <pitch y>                     > 0
 *   registration chief|window|channel                optional (chief): below
 *   wavelengths_nm <n> <l_1> ... <l_n>               strictly increasing, > 0
 *   f_numbers <n> <v_1> ... <v_n>                    distinct, > 0
 *   focus_offsets_mm <n> <v_1> ... <v_n>             distinct
 *   distances_mm <n> <v_1> ... <v_n>                 distinct, >= 0 (0: infinity)
 *   field_x_deg <n> <v_1> ... <v_n>                  strictly increasing
 *   field_y_deg <n> <v_1> ... <v_n>                  strictly increasing
 *   nodes <N>                                        N = the product of the five counts
 *   node <k> <i_f> <i_z> <i_d> <i_y> <i_x> <center_x_mm> <center_y_mm> <error_estimate>
 *        <crc32 of the EXR file, 8 hex> <path of the EXR relative to the index's folder>
 *   chief <k> <x_1> <y_1> ... <x_n> <y_n>            the chief ray's image point (mm) at
 *                                                    each wavelength
 *   ... a node line and its chief line for each k = 0 .. N-1, in order
 *   checksum crc32 <8 lowercase hex digits>          CRC-32 of every byte before this line
 *
 * Every index tuple (i_f, i_z, i_d, i_y, i_x) appears exactly once. A node's EXR is
 * width x height pixels of the bank's pitch centred on (center_x_mm, center_y_mm), as a
 * render's window (lensrt_sensor) is: row 0 at the top (+y), pixel (i, j)'s centre at
 * (center_x + (i + 0.5 - width / 2) pitch_x, center_y + (height / 2 - j - 0.5) pitch_y).
 * With `registration channel` (since 0.9.0; what lensfit writes for a bank of PSFs) each
 * channel of a node is a window of its own centred on that wavelength's chief point, so
 * that no channel is ever resampled: node_center is informative only, and the EXR must
 * name its node in the string attribute "lensrt/bankNode", "<i_f> <i_z> <i_d> <i_y> <i_x>
 * <f_number> <focus_offset_mm> <distance_mm> <field_x_deg> <field_y_deg>" (the index's
 * values, read back exactly; an EXR of another node is refused). With `registration
 * chief` (or no registration line) each node's window is placed on its chief point
 * (which must lie inside it), and lensrt_bank_psf registers each channel on its chief
 * point by a bilinear shift (which blurs: a shift of 2-9 pixels cost 6-25% at the outer
 * wavelengths of a bank of lens 0009); with `registration window` the nodes share one
 * window (flare banks: a light's ghosts far from its image) and are blended in place,
 * pixel for pixel.
 * A node EXR may also hold layers ("<layer>.S0.<lambda>nm", lensrt_layers_write_exr):
 * they are ignored, the unprefixed channels being their sum.
 * error_estimate is the node's relative L2 error estimate (>= 0; -1: none). Paths use
 * only [A-Za-z0-9._/-], and are relative (no leading '/', no "..", no empty component).
 * At most LENSRT_MAX_BANK_NODES nodes and LENSRT_MAX_WAVELENGTHS wavelengths.
 *
 * lensrt_bank_open checks everything it reads as the table reader does: the checksum
 * line first, then every line (keys in order, counts, finite numbers, ranges, node
 * indices, duplicates, paths), and that each node's EXR is a regular file. A node's EXR
 * is read when a query first needs it (since 0.9.0; lensrt_bank_load_nodes reads them
 * all now), so opening a bank of LENSRT_MAX_BANK_NODES nodes takes memory for its index
 * only: its bytes must have the CRC-32 the index gives, and its image must be width x
 * height FLOAT pixels (one scanline part, data window from 0, 0) with exactly the index's
 * spectral channels (plus R, G, B), every value finite and >= 0. Any failure is
 * LENSRT_ERROR_PARSE (or _IO for a file that cannot be read; _UNSUPPORTED in a build
 * without OpenEXR) with a message naming the file (the index or the EXR), the line or
 * the node, the key and the value, from lensrt_bank_open, lensrt_bank_load_nodes or the
 * query that needed the node (a node that failed is read again by the next query that
 * needs it). Node images once read are kept in memory (through the context's allocator)
 * until the bank is closed: width x height x wavelengths x 4 bytes each. A bank is used
 * from one thread at a time (its messages go to its context); close it before
 * destroying that context. */
#define LENSRT_MAX_BANK_NODES 65536

typedef struct lensrt_bank_s *lensrt_bank;

typedef struct lensrt_bank_info {
    size_t struct_size;          /* sizeof(lensrt_bank_info): LENSRT_BANK_INFO_INIT */
    const char *lens_name;       /* valid while the bank lives, as are the arrays below */
    uint32_t table_crc32;
    int32_t width, height;       /* pixels of every node image */
    double pixel_x_mm, pixel_y_mm;
    int32_t n_wavelengths;
    const double *wavelengths_nm;
    int32_t n_f_numbers;
    const double *f_numbers;
    int32_t n_focus_offsets;
    const double *focus_offsets_mm;
    int32_t n_distances;
    const double *distances_mm;
    int32_t n_field_x;
    const double *field_x_deg;
    int32_t n_field_y;
    const double *field_y_deg;
    int32_t n_nodes;
    double worst_error_estimate; /* the largest of the nodes' error estimates; -1 when a
                                    node has none (the worst is then unknown) */
} lensrt_bank_info;
#define LENSRT_BANK_INFO_INIT {sizeof(lensrt_bank_info), NULL, 0, 0, 0, 0, 0, 0, NULL, 0, NULL, 0, NULL, \
                               0, NULL, 0, NULL, 0, NULL, 0, 0}

typedef struct lensrt_bank_query {
    size_t struct_size;          /* sizeof(lensrt_bank_query): LENSRT_BANK_QUERY_INIT */
    double field_x_deg, field_y_deg; /* within the bank's field grid (interpolated) */
    double wavelength_nm;        /* within the bank's wavelengths (interpolated) */
    double f_number;             /* one of the bank's f-numbers; 0: the first */
    double focus_offset_mm;      /* one of the bank's (exact) */
    double distance_mm;          /* one of the bank's (exact; 0: infinity) */
    /* Since 0.9.0: the chief point the caller knows (lensrt_lens_image_point of the bank's
     * lens at this field point, wavelength, focus and distance), used instead of the
     * interpolated one when chief_given is 1. With 3 field points per axis the
     * interpolated one can be pixels off (4 px at the cell centres of banks/demo.toml's
     * y axis: 0.36% of distortion at its edge); with 5, 0.03 px. */
    int32_t chief_given;
    double chief_x_mm, chief_y_mm;
} lensrt_bank_query;
#define LENSRT_BANK_QUERY_INIT {sizeof(lensrt_bank_query), 0, 0, 0, 0, 0, 0, 0, 0, 0}

/* Open the bank whose index is index_path (node paths are relative to its folder). */
LENSRT_API lensrt_result lensrt_bank_open(lensrt_context ctx, const char *index_path, lensrt_bank *out);
/* Read, check and keep every node's image now (what a query does for the nodes it
 * needs): the first failure, naming its node. */
LENSRT_API lensrt_result lensrt_bank_load_nodes(lensrt_bank bank);
/* Free the bank (NULL: nothing). */
LENSRT_API void lensrt_bank_close(lensrt_bank bank);
LENSRT_API lensrt_result lensrt_bank_get_info(lensrt_bank bank, lensrt_bank_info *out);

/* The PSF at a field point and wavelength: width x height floats (the node images' units
 * and row order, row 0 at the top, out[j * width + i]), on the bank's pixel grid centred
 * on the interpolated chief-ray image point, which is written to chief_mm (may be NULL).
 *
 * The f-number, focus offset and distance pick a slice of the bank by exact match (f_number
 * 0: the first); a value the bank does not hold is LENSRT_ERROR_OUT_OF_DOMAIN with a
 * message listing the bank's values. In the slice, the field point's cell gives weights
 * over up to 4 x 4 nodes around it: the Lagrange polynomial in (tan field_x, tan field_y)
 * through 4 nodes on each axis (the cell's two and one on each side, or the 4 nearest at
 * the grid's ends; all of them on an axis of fewer; along an axis with one value the
 * query must equal it); each node's image at the wavelength
 * is the linear blend of its two bracketing channels, each channel registered on its own
 * chief point: output pixel (i, j), at offset o = ((i + 0.5 - width / 2) pitch_x,
 * (height / 2 - j - 0.5) pitch_y) from the output's centre, takes channel c at the point
 * chief_c + o of the channel's window, by bilinear interpolation between its pixel
 * centres (zero outside it; with `registration channel` that is the channel's pixel
 * (i, j) itself). The images are added with those weights (partly negative: a pixel
 * whose sum is negative is 0), and the output's centre (chief_mm) is the chief points
 * with the same weights (linear in wavelength): exact for a lens without distortion, and
 * a cubic in its distortion. A cubic rather than bilinear blend: at the cell centres of
 * banks/demo.toml (lens 0001, f/8, every 2.5 x 3.25 deg) 3-23% from direct renders
 * against 6-26% (make bench, banks.md). At a node and one of its wavelengths the output is that
 * channel of the node's EXR bit for bit (with `registration chief`, at the wavelength
 * whose chief point is the node's centre). A bank of `registration window` blends
 * its nodes' images in place (no shift; the output is the shared window, chief_mm still
 * the blended chief point). A field angle or wavelength outside the
 * bank's range: LENSRT_ERROR_OUT_OF_DOMAIN naming the value and the range; one that is
 * not finite, or count other than width x height: LENSRT_ERROR_INVALID_ARGUMENT. */
LENSRT_API lensrt_result lensrt_bank_psf(lensrt_bank bank, const lensrt_bank_query *query, float *out, size_t count,
                                         double chief_mm[2]);

/* ------------------------------------------------- an image through the lens ----- */

/* Since 0.11.0 (issue 38): a caller's framebuffer as the sensor behind the lens records it.
 *
 * The input is a linear pinhole image of the scene: n_channels planes of width x height
 * floats (finite, >= 0; plane-major, row 0 at the top, +y), whose pixel (i, j) has its
 * centre at the sensor point (x, y) = (center_x + (i + 0.5 - width / 2) pitch_x,
 * center_y + (height / 2 - j - 0.5) pitch_y) mm (pitch: the bank's times oversample),
 * and holds the light
 * that a pinhole of focal length (focal_x, focal_y) mm sees there: the scene direction of
 * field angles (atan(x / focal_x), atan(y / focal_y)) (lensrt_light's convention).
 * Channel c is light of the spectrum channel_weights[c][l] over the bank's wavelengths
 * l, recorded in channel c (no crosstalk between channels: RGB input is upsampled by the
 * caller's choice of weights, spectral input is one channel per bank wavelength).
 *
 * The output layers, each n_channels planes as the input:
 *   LENSRT_IMAGE_DIRECT  every pixel's light through its own field point's PSF: the
 *                        bank's nodes interpolated in field (weights continuous across
 *                        the cells, so no seams), each node's PSF applied by FFT
 *                        convolution to the light its weights give it, after the
 *                        light is moved to where the lens images it (the chief points:
 *                        distortion) and with the power the bank's PSFs carry relative to
 *                        the axis's (vignetting, transmission); a pixel whose light is on
 *                        the axis and the PSF's all on the sensor keeps its power.
 *   LENSRT_IMAGE_FLARE   the sum of the ghost layers.
 *   LENSRT_IMAGE_GHOST + g  ghost table g's images of the sources: the input's pixels
 *                        above flare_threshold, grouped into connected sources (each at
 *                        its power-weighted field point, with its summed light), the
 *                        max_sources brightest kept; each ghost rendered per source by
 *                        lensrt_render_integrate_fourier/cells to flare_target_error,
 *                        in units of the direct layer's (relative to the axis PSF's power).
 * A frame reaching outside the bank's field grid, or a source outside a ghost's fitted
 * field, is LENSRT_ERROR_OUT_OF_DOMAIN naming the value and the range. */
typedef struct lensrt_image_s *lensrt_image;

enum lensrt_image_layer {
    LENSRT_IMAGE_DIRECT = 0,
    LENSRT_IMAGE_FLARE = 1,
    LENSRT_IMAGE_GHOST = 2        /* + ghost index */
};

typedef struct lensrt_image_desc {
    size_t struct_size;           /* sizeof(lensrt_image_desc): LENSRT_IMAGE_DESC_INIT */
    lensrt_bank bank;             /* the direct PSFs (registration channel); borrowed: it
                                     must outlive the image */
    double f_number;              /* the bank's slice, as lensrt_bank_query (0: the first) */
    double focus_offset_mm;
    double distance_mm;           /* 0: infinity */
    int32_t width, height;        /* framebuffer pixels, 1 .. LENSRT_MAX_RESOLUTION */
    double center_x_mm, center_y_mm; /* the frame's centre on the sensor */
    double focal_x_mm, focal_y_mm;   /* the pinhole's focal lengths (> 0; focal_y 0: focal_x) */
    int32_t n_channels;           /* 1 .. LENSRT_MAX_WAVELENGTHS */
    const double *channel_weights; /* n_channels x the bank's wavelengths, row-major, >= 0,
                                     each row summing to > 0 (copied); NULL: one channel
                                     per bank wavelength (n_channels must equal it) */
    const lensrt_lens *ghosts;    /* ghost tables of the bank's lens (copied array; the
                                     lenses are borrowed); NULL with n_ghosts 0: no flares */
    int32_t n_ghosts;             /* 0 .. LENSRT_MAX_LAYERS - 2 */
    lensrt_aperture aperture;     /* the ghost renders' (radius 0 and f_number 0: the bank
                                     slice's f_number, circle) */
    double flare_threshold;       /* sources: pixels whose channel sum exceeds this; 0: the
                                     input's largest channel sum / 16 */
    int32_t max_sources;          /* the brightest sources kept; 0: 16 */
    double flare_target_error;    /* each ghost render's relative L2 estimate; 0: 0.02 */
    int32_t flare_downsample;     /* framebuffer pixels per ghost-render pixel, per axis
                                     (ghosts are smooth); 0: 4 */
    /* The direct layer on a grid this many times finer per axis (1 .. 16; 0: 1), whose
     * pitch the bank's must be (the frame's pitch is the bank's times this): each
     * framebuffer pixel's light is spread evenly over its sub-pixels (a pixel is the
     * light of its footprint), put through, and averaged back over each pixel. Against
     * every lit pixel's own PSF (lens 0001, f/8, 18.75 um pixels) 2: 5%, 3: 2.4%, 4:
     * 1.5% relative L2, at oversample^2 times the convolutions' cost (make bench,
     * docs/image.md). */
    int32_t oversample;
    /* Since 0.12.0. LENSRT_IMAGE_MIRROR_X: the lens is mirror-symmetric about x = 0 (every
     * lens lensfit fits is, about both axes) and the bank's field_x_deg are all >= 0: a
     * field point at -x takes the bank's PSFs at +x mirrored in x, and its chief points'
     * x negated, exactly (each window is centred on its chief point). The
     * frame's field grid is the bank's with its mirror image. LENSRT_IMAGE_MIRROR_Y
     * likewise in y. A bank over a quadrant is a quarter of the renders. 0: none. */
    int32_t mirror;
} lensrt_image_desc;
#define LENSRT_IMAGE_DESC_INIT {sizeof(lensrt_image_desc), NULL, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, NULL, \
                                NULL, 0, {0, 0, 0, 0, 0, 0, 0, 0}, 0, 0, 0, 0, 0, 0}
#define LENSRT_IMAGE_MIRROR_X 1
#define LENSRT_IMAGE_MIRROR_Y 2

/* What the last lensrt_image_run did, and what each part cost (wall seconds). */
typedef struct lensrt_image_stats {
    size_t struct_size;           /* sizeof(lensrt_image_stats): LENSRT_IMAGE_STATS_INIT */
    double seconds_warp;          /* light moved to its chief points, split over the nodes */
    double seconds_kernels;       /* node PSFs read from the bank and transformed */
    double seconds_convolve;      /* the FFT convolutions and their sum */
    double seconds_flares;        /* sources found and their ghosts rendered */
    int32_t n_nodes;              /* bank nodes that received light */
    int32_t fft_width, fft_height; /* the largest transform */
    int32_t n_sources;            /* sources kept */
    int32_t n_ghost_renders;      /* ghost renders made (ghosts that miss the frame skipped) */
    double worst_flare_error;     /* the largest ghost render error estimate; -1: none */
} lensrt_image_stats;
#define LENSRT_IMAGE_STATS_INIT {sizeof(lensrt_image_stats), 0, 0, 0, 0, 0, 0, 0, 0, 0, 0}

/* A source the last run found (brightest first). */
typedef struct lensrt_image_source {
    size_t struct_size;           /* sizeof(lensrt_image_source): LENSRT_IMAGE_SOURCE_INIT */
    double field_x_deg, field_y_deg; /* its power-weighted field point */
    double power;                 /* the sum of its pixels' channel sums */
    int32_t pixels;               /* how many pixels it has */
} lensrt_image_source;
#define LENSRT_IMAGE_SOURCE_INIT {sizeof(lensrt_image_source), 0, 0, 0, 0}

/* Check the description against the bank (slice, field grid covering the frame's
 * pinhole fields, pitch) and the ghosts, and allocate. Messages name the key and value. */
LENSRT_API lensrt_result lensrt_image_create(lensrt_context ctx, const lensrt_image_desc *desc,
                                             lensrt_image *out);
/* Free the image (NULL: nothing). */
LENSRT_API void lensrt_image_destroy(lensrt_image image);
/* Put one framebuffer through the lens: count = n_channels x width x height. A value that
 * is not finite or is negative is LENSRT_ERROR_INVALID_ARGUMENT naming the channel and
 * pixel. The layers are kept until the next run. */
LENSRT_API lensrt_result lensrt_image_run(lensrt_image image, const float *input, size_t count);
/* One output layer (enum lensrt_image_layer) of the last run into out (count as the input). */
LENSRT_API lensrt_result lensrt_image_get_layer(lensrt_image image, int32_t layer, float *out,
                                                size_t count);
LENSRT_API lensrt_result lensrt_image_get_stats(lensrt_image image, lensrt_image_stats *out);
/* Source i (0 .. stats.n_sources - 1) of the last run. */
LENSRT_API lensrt_result lensrt_image_get_source(lensrt_image image, int32_t i,
                                                 lensrt_image_source *out);

#ifdef __cplusplus
}
#endif
#endif /* LENSRT_H */
