# lensrt_add_lens: compile a fitted lens into a target (lensrt_lens_load_compiled).
#
#   lensrt_add_lens(<target> <lens folder> [SYMBOL <c name>] [TABLE <file>])
#
# <lens folder> is a folder lensfit wrote, e.g. generated/0001-angenieux-double-gauss/ or
# a scene fit's generated/<lens>/scene-fits/<scene>/ (relative paths are taken from the
# current source folder). It holds one coefficient table lens<ID>.table (TABLE names it
# when there are several; relative to the folder) and the generated Horner code
# lens<ID>.c / lens<ID>.h of the same fit. lensrt_add_lens
#   * adds lens<ID>.c to the target's sources (PRIVATE), compiled with the target's own
#     flags, and the folder to its include path;
#   * generates at build time, from the table (so a refit rebuilds it), <symbol>.c which
#     embeds the table's text and defines `const lensrt_compiled_lens <symbol>` with the
#     four Horner evaluators lens<ID>_P_o_d, _P_s_d, _P_o_f, _P_s_f; and <symbol>.h,
#     which declares it, on the target's include path. The default symbol is
#     lensrt_lens_<ID> (lensrt_lens_0001).
# The target links lensrt::lensrt (for lensrt.h and lensrt_lens_load_compiled):
#
#   lensrt_add_lens(my_renderer ${LENSES}/0001-angenieux-double-gauss)
#   target_link_libraries(my_renderer PRIVATE lensrt::lensrt)
#
#   #include "lensrt_lens_0001.h"
#   lensrt_lens_load_compiled(ctx, &lensrt_lens_0001, &lens);
#
# A scene specialisation (`lensfit scene`, generated/<lens>/scenes/<scene>/) is refused:
# its systems are P_o per light and P_s without the sensor shift, which lensrt does not
# load; a scene fit (`lensfit fit <ID> --scene <scene>.toml`) is the compact lens for a
# scene that lensrt loads. A lens and its scene fit both name their code lens<ID>: one
# target takes one of them (their Horner functions would collide); several lenses of
# different IDs are fine. Call lensrt_add_lens in the folder that made the target. The
# generated C is large (2.6 MB for 0001: about 4 s to compile at -O0 and 22 s at -O2);
# set_source_files_properties(<folder>/lens<ID>.c PROPERTIES COMPILE_OPTIONS ...) tunes
# it alone.
#
# Included from the source tree (include(cmake/lensrt_add_lens.cmake)) and by an
# installed package's lensrtConfig.cmake, next to embed_text.cmake in both.
include_guard(GLOBAL)
# A global property, not a variable: the function may be called from folders that do
# not see the variables of the one that included this file first
set_property(GLOBAL PROPERTY LENSRT_EMBED_TEXT_SCRIPT "${CMAKE_CURRENT_LIST_DIR}/embed_text.cmake")

function(lensrt_add_lens target folder)
  cmake_parse_arguments(PARSE_ARGV 2 ARG "" "SYMBOL;TABLE" "")
  get_property(embed_text GLOBAL PROPERTY LENSRT_EMBED_TEXT_SCRIPT)
  set(fn "lensrt_add_lens(${target} ${folder})")
  if(ARG_UNPARSED_ARGUMENTS)
    message(FATAL_ERROR "${fn}: unknown arguments '${ARG_UNPARSED_ARGUMENTS}' "
                        "(expected [SYMBOL <c name>] [TABLE <file>])")
  endif()
  if(NOT TARGET ${target})
    message(FATAL_ERROR "${fn}: no target '${target}' (make it first)")
  endif()
  get_filename_component(folder "${folder}" ABSOLUTE BASE_DIR "${CMAKE_CURRENT_SOURCE_DIR}")
  if(NOT IS_DIRECTORY "${folder}")
    message(FATAL_ERROR "${fn}: no folder ${folder}")
  endif()

  # The table: TABLE, or the one lens*.table of the folder
  if(ARG_TABLE)
    get_filename_component(table "${ARG_TABLE}" ABSOLUTE BASE_DIR "${folder}")
    if(NOT EXISTS "${table}")
      message(FATAL_ERROR "${fn}: no table ${table}")
    endif()
  else()
    file(GLOB tables "${folder}/lens*.table")
    list(LENGTH tables n_tables)
    if(NOT n_tables EQUAL 1)
      message(FATAL_ERROR "${fn}: expected one lens<ID>.table in ${folder}, found ${n_tables} "
                          "(${tables}); name it with TABLE <file>")
    endif()
    set(table "${tables}")
  endif()

  # The generated C of the same fit, named after the table: lens<ID>.c and lens<ID>.h
  get_filename_component(stem "${table}" NAME_WE)
  if(NOT stem MATCHES "^lens([A-Za-z0-9_]+)$")
    message(FATAL_ERROR "${fn}: ${table} is not named lens<ID>.table")
  endif()
  set(id "${CMAKE_MATCH_1}")
  foreach(ext c h)
    if(NOT EXISTS "${folder}/${stem}.${ext}")
      message(FATAL_ERROR "${fn}: no ${stem}.${ext} in ${folder} (lensfit writes it with the table)")
    endif()
  endforeach()
  file(STRINGS "${folder}/${stem}.h" declared REGEX "^void ${stem}_P_[os]_[df]\\(")
  list(LENGTH declared n_declared)
  if(NOT n_declared EQUAL 4)
    message(FATAL_ERROR "${fn}: ${stem}.h does not declare ${stem}_P_o_d, _P_s_d, _P_o_f and _P_s_f. "
                        "A scene specialisation (lensfit scene: P_o per light, P_s without z_S) is "
                        "not a lens lensrt loads; compile the lens folder, or a scene fit "
                        "(lensfit fit <ID> --scene <scene>.toml writes generated/<lens>/scene-fits/<scene>/)")
  endif()

  # The C name, and the lens's name in messages: the folder's, with its lens for a scene fit
  set(symbol "lensrt_lens_${id}")
  if(ARG_SYMBOL)
    set(symbol "${ARG_SYMBOL}")
  endif()
  if(NOT symbol MATCHES "^[A-Za-z_][A-Za-z0-9_]*$")
    message(FATAL_ERROR "${fn}: SYMBOL '${symbol}' is not a C identifier")
  endif()
  get_filename_component(name "${folder}" NAME)
  get_filename_component(parent "${folder}" DIRECTORY)
  get_filename_component(parent_name "${parent}" NAME)
  if(parent_name STREQUAL "scene-fits")
    get_filename_component(lens_folder "${parent}" DIRECTORY)
    get_filename_component(lens_name "${lens_folder}" NAME)
    set(name "${lens_name}/scene-fits/${name}")
  endif()
  string(REPLACE "\\" "\\\\" c_name "${name}")
  string(REPLACE "\"" "\\\"" c_name "${c_name}")
  string(TOUPPER "${symbol}_H" guard)

  # The header and the struct's definition depend only on names: written now. The array
  # of the table's text between them comes at build time (cmake/embed_text.cmake).
  set(out "${CMAKE_CURRENT_BINARY_DIR}/lensrt_lenses/${target}/${symbol}")
  file(CONFIGURE OUTPUT "${out}/${symbol}.h" @ONLY CONTENT
"/* Generated by lensrt_add_lens (cmake/lensrt_add_lens.cmake) from
 * @table@; do not edit. */
#ifndef @guard@
#define @guard@

#include <lensrt.h>

#ifdef __cplusplus
extern \"C\" {
#endif

/* The lens @name@, compiled in: lensrt_lens_load_compiled(ctx, &@symbol@, &lens). */
extern const lensrt_compiled_lens @symbol@;

#ifdef __cplusplus
}
#endif

#endif
")
  file(CONFIGURE OUTPUT "${out}/head.c.in" @ONLY CONTENT
"#include \"@symbol@.h\"
#include \"@stem@.h\"

/* The coefficient table (@table@) */
")
  file(CONFIGURE OUTPUT "${out}/tail.c.in" @ONLY CONTENT
"
const lensrt_compiled_lens @symbol@ = {
    .struct_size = sizeof(lensrt_compiled_lens),
    .name = \"@c_name@\",
    .table_text = @symbol@_table,
    .table_size = sizeof @symbol@_table - 1,
    .object_d = @stem@_P_o_d, .sensor_d = @stem@_P_s_d,
    .object_f = @stem@_P_o_f, .sensor_f = @stem@_P_s_f
};
")
  add_custom_command(OUTPUT "${out}/${symbol}.c"
    COMMAND "${CMAKE_COMMAND}" "-DOUT=${out}/${symbol}.c" "-DINPUTS=${table}" "-DSYMBOLS=${symbol}_table"
            -DSTATIC=ON "-DHEAD=${out}/head.c.in" "-DTAIL=${out}/tail.c.in" -P "${embed_text}"
    DEPENDS "${table}" "${embed_text}" "${out}/head.c.in" "${out}/tail.c.in"
    COMMENT "Embedding the lens table ${stem}.table as ${symbol}" VERBATIM)
  target_sources(${target} PRIVATE "${folder}/${stem}.c" "${out}/${symbol}.c")
  target_include_directories(${target} PRIVATE "${folder}" "${out}")
endfunction()
