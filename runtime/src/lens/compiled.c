/* Compiled-in lenses (lensrt_lens_load_compiled): a lens linked into the program by
 * lensrt_add_lens (cmake/lensrt_add_lens.cmake), its coefficient table embedded as text
 * and its generated Horner evaluators compiled with the caller's code.
 *
 * The lens is made from the embedded table exactly as lensrt_lens_load makes it from the
 * file (lensrt_lens_load_text), so renders, which read only the coefficients, are the
 * same bit for bit; the Horner functions are kept for lensrt_lens_eval's values. Nothing
 * is copied: the caller's struct (static data in practice) must outlive the lens. */
#include "../internal.h"

#include <stddef.h>

/* The oldest struct layout that has this function (lensrt 0.2) ends with sensor_f: a
 * smaller struct_size is not a struct of this API. */
#define COMPILED_MIN_SIZE (offsetof(lensrt_compiled_lens, sensor_f) + sizeof(lensrt_horner_f))

lensrt_result lensrt_lens_load_compiled(lensrt_context ctx, const lensrt_compiled_lens *compiled,
                                        lensrt_lens *out)
{
    const char *what = "lensrt_lens_load_compiled";
    lensrt_compiled_lens c; /* the fields this library knows, to check them */
    const char *name;
    lensrt_result res;
    if (!ctx || !compiled || !out) return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "%s: NULL argument", what);
    *out = NULL;
    // The struct's size first (the ABI rules of lensrt.h): 0 is a struct zeroed by hand,
    // less than the first layout is not this struct, more is a newer header's struct,
    // accepted only when the fields this library does not know are zero
    if (compiled->struct_size < COMPILED_MIN_SIZE)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "%s: struct_size is %zu, expected sizeof(lensrt_compiled_lens) = %zu (the struct "
                           "that lensrt_add_lens generates sets it)", what, compiled->struct_size,
                           sizeof(lensrt_compiled_lens));
    res = lensrt_struct_in(ctx, what, compiled, &c, sizeof c);
    if (res != LENSRT_SUCCESS) return res;
    // Then the fields: a name for messages, the table, and all four evaluators
    name = c.name;
    if (!name || !name[0])
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "%s: the lens has no name (name is %s)", what,
                           name ? "\"\"" : "NULL");
    if (!c.table_text || c.table_size == 0)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "%s: lens %s: table_text is %s and table_size %zu; "
                           "a compiled-in lens carries its coefficient table", what, name,
                           c.table_text ? "set" : "NULL", c.table_size);
    if (!c.object_d || !c.sensor_d || !c.object_f || !c.sensor_f)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "%s: lens %s: the Horner evaluator %s is NULL (a compiled-in lens has all four)", what,
                           name, !c.object_d ? "object_d" : !c.sensor_d ? "sensor_d"
                                 : !c.object_f ? "object_f" : "sensor_f");
    // The lens itself, from the embedded table as from a file; messages name the lens
    res = lensrt_lens_load_text(ctx, c.table_text, c.table_size, name, out);
    if (res != LENSRT_SUCCESS) return res;
    (*out)->compiled = compiled;
    return LENSRT_SUCCESS;
}
