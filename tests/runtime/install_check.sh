#!/usr/bin/env bash
# install_check: install a lensrt build into a scratch prefix and use it the way an
# out-of-tree renderer would.
#
#   tests/runtime/install_check.sh BUILD_DIR SCRATCH [LIBDIR]
#
#   1. cmake --install BUILD_DIR --prefix SCRATCH/prefix
#   2. examples/find_package through find_package(lensrt CONFIG) into SCRATCH/example-cmake,
#      run it (CMake's build RPATH finds liblensrt.so in the prefix); with it
#      lensrt-example-compiled, the demo scene fit of lens 0001 compiled in by the
#      package's lensrt_add_lens (0.5 MB of generated C, a few seconds)
#   3. examples/find_package/main.c compiled with `pkg-config --cflags --libs lensrt`
#      into SCRATCH/example-pkgconfig, run it with LD_LIBRARY_PATH=PREFIX/LIBDIR
#   4. the installed lensrt-psf --help (its install RPATH finds the library)
#
# LIBDIR is CMAKE_INSTALL_LIBDIR of the build (lib, or lib/x86_64-linux-gnu for a /usr
# prefix); default: read from BUILD_DIR/CMakeCache.txt. Everything is written under
# SCRATCH (and BUILD_DIR/install_manifest.txt by cmake --install). Exits non-zero with a
# message naming the step on any failure.
set -u -o pipefail

die() {
    echo "install_check: FAILED: $*" >&2
    exit 1
}
step() { echo "install_check: $*"; }

[ $# -ge 2 ] && [ $# -le 3 ] || { echo "usage: $0 BUILD_DIR SCRATCH [LIBDIR]" >&2; exit 2; }
BUILD_DIR=$(cd "$1" 2> /dev/null && pwd) || die "no build folder '$1'"
mkdir -p "$2" || die "cannot create the scratch folder '$2'"
SCRATCH=$(cd "$2" && pwd)
SOURCE_DIR=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
EXAMPLE="$SOURCE_DIR/examples/find_package"
CACHE="$BUILD_DIR/CMakeCache.txt"
[ -f "$CACHE" ] || die "$BUILD_DIR is not a configured CMake build (no CMakeCache.txt)"
[ -f "$EXAMPLE/CMakeLists.txt" ] && [ -f "$EXAMPLE/main.c" ] || die "no example in $EXAMPLE"

cache_value() { sed -n "s/^$1:[A-Z]*=//p" "$CACHE" | head -n 1; }
CACHED_LIBDIR=$(cache_value CMAKE_INSTALL_LIBDIR)
LIBDIR=${3:-$CACHED_LIBDIR}
[ -n "$LIBDIR" ] || die "CMAKE_INSTALL_LIBDIR is not in $CACHE and was not given"
[ -z "$CACHED_LIBDIR" ] || [ "$LIBDIR" = "$CACHED_LIBDIR" ] ||
    die "LIBDIR '$LIBDIR' differs from CMAKE_INSTALL_LIBDIR '$CACHED_LIBDIR' in $CACHE"
CC_BIN=$(cache_value CMAKE_C_COMPILER)
CC_BIN=${CC_BIN:-${CC:-cc}}
SANITIZE=$(cache_value LENSRT_SANITIZE)
BINDIR=$(cache_value CMAKE_INSTALL_BINDIR)
INCLUDEDIR=$(cache_value CMAKE_INSTALL_INCLUDEDIR)
BINDIR=${BINDIR:-bin}
INCLUDEDIR=${INCLUDEDIR:-include}

PREFIX="$SCRATCH/prefix"
case "$LIBDIR" in
    /*) LIB="$LIBDIR" ;;
    *) LIB="$PREFIX/$LIBDIR" ;;
esac
# A fresh prefix and fresh example builds each time; nothing but SCRATCH is touched
rm -rf "$PREFIX" "$SCRATCH/example-cmake" "$SCRATCH/example-pkgconfig"
unset DESTDIR LD_LIBRARY_PATH PKG_CONFIG_PATH PKG_CONFIG_LIBDIR CMAKE_PREFIX_PATH lensrt_DIR
if [ "$SANITIZE" = ON ]; then
    # Sanitized builds: leaks fail the example as they fail the tests
    export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1}
    export UBSAN_OPTIONS=${UBSAN_OPTIONS:-halt_on_error=1:print_stacktrace=1}
fi

# ---------------------------------------------------------------- 1. install -----
step "cmake --install $BUILD_DIR --prefix $PREFIX (libdir $LIBDIR)"
cmake --install "$BUILD_DIR" --prefix "$PREFIX" > "$SCRATCH/install.log" 2>&1 ||
    { cat "$SCRATCH/install.log" >&2; die "cmake --install"; }
for f in "$INCLUDEDIR/lensrt.h" "$BINDIR/lensrt-psf"; do
    [ -f "$PREFIX/$f" ] || die "install: $PREFIX/$f is missing"
done
for f in liblensrt.so pkgconfig/lensrt.pc cmake/lensrt/lensrtConfig.cmake \
    cmake/lensrt/lensrtConfigVersion.cmake cmake/lensrt/lensrtTargets.cmake \
    cmake/lensrt/lensrt_add_lens.cmake cmake/lensrt/embed_text.cmake; do
    [ -e "$LIB/$f" ] || die "install: $LIB/$f is missing (is the libdir really '$LIBDIR'?)"
done
# (the prefix may itself lie inside the build folder, as it does under ctest)
if cat "$LIB/pkgconfig/lensrt.pc" "$LIB"/cmake/lensrt/*.cmake | sed "s|$PREFIX||g" | grep -qF "$BUILD_DIR"; then
    die "install: the package files name the build folder $BUILD_DIR"
fi

# liblensrt must come from the prefix: ask the dynamic loader which one it would load
expect_prefix_lib() { # NAME PROGRAM [VAR=VALUE...]
    local name=$1 program=$2 got
    shift 2
    got=$(env "$@" LD_TRACE_LOADED_OBJECTS=1 "$program" 2> /dev/null |
        sed -n 's/^[[:space:]]*liblensrt\.so[^ ]* => \([^ ]*\).*/\1/p' | head -n 1)
    [ -n "$got" ] && [ "$(dirname "$(readlink -f "$got")")" = "$(readlink -f "$LIB")" ] ||
        die "$name loads liblensrt from '${got:-nowhere}', not from $LIB"
}

# ------------------------------------------------- 2. find_package(lensrt CONFIG) -----
step "find_package: configure and build $EXAMPLE into $SCRATCH/example-cmake"
cmake -S "$EXAMPLE" -B "$SCRATCH/example-cmake" -DCMAKE_PREFIX_PATH="$PREFIX" \
    -DLENSRT_EXAMPLE_LENS="$SOURCE_DIR/generated/0001-angenieux-double-gauss/scene-fits/demo" \
    -DCMAKE_C_COMPILER="$CC_BIN" -DCMAKE_BUILD_TYPE=Release \
    -DCMAKE_FIND_USE_PACKAGE_REGISTRY=OFF > "$SCRATCH/example-cmake.log" 2>&1 ||
    { cat "$SCRATCH/example-cmake.log" >&2; die "find_package example: configure"; }
FOUND_DIR=$(sed -n 's/^lensrt_DIR:PATH=//p' "$SCRATCH/example-cmake/CMakeCache.txt")
[ "$FOUND_DIR" = "$LIB/cmake/lensrt" ] ||
    die "find_package example: found lensrt in '$FOUND_DIR', expected $LIB/cmake/lensrt"
cmake --build "$SCRATCH/example-cmake" >> "$SCRATCH/example-cmake.log" 2>&1 ||
    { cat "$SCRATCH/example-cmake.log" >&2; die "find_package example: build"; }
expect_prefix_lib "the find_package example" "$SCRATCH/example-cmake/lensrt-example"
step "run $SCRATCH/example-cmake/lensrt-example"
"$SCRATCH/example-cmake/lensrt-example" || die "find_package example: run (exit status $?)"
step "run $SCRATCH/example-cmake/lensrt-example-compiled (lensrt_add_lens from the package)"
expect_prefix_lib "the compiled-lens example" "$SCRATCH/example-cmake/lensrt-example-compiled"
"$SCRATCH/example-cmake/lensrt-example-compiled" || die "compiled-lens example: run (exit status $?)"

# ------------------------------------------------------------- 3. pkg-config -----
step "pkg-config: compile main.c with PKG_CONFIG_PATH=$LIB/pkgconfig"
command -v pkg-config > /dev/null || die "pkg-config is not installed"
PC_CFLAGS=$(PKG_CONFIG_PATH="$LIB/pkgconfig" pkg-config --cflags lensrt) || die "pkg-config --cflags lensrt"
PC_LIBS=$(PKG_CONFIG_PATH="$LIB/pkgconfig" pkg-config --libs lensrt) || die "pkg-config --libs lensrt"
case " $PC_CFLAGS " in *" -I$PREFIX/$INCLUDEDIR "*) ;; *) die "pkg-config --cflags gives '$PC_CFLAGS', without -I$PREFIX/$INCLUDEDIR" ;; esac
case " $PC_LIBS " in *" -L$LIB "*) ;; *) die "pkg-config --libs gives '$PC_LIBS', without -L$LIB" ;; esac
mkdir -p "$SCRATCH/example-pkgconfig"
# shellcheck disable=SC2086 # word splitting of the flags is intended
"$CC_BIN" -std=c99 -Wall -Wextra -pedantic -Werror $PC_CFLAGS "$EXAMPLE/main.c" \
    -o "$SCRATCH/example-pkgconfig/lensrt-example" $PC_LIBS ||
    die "pkg-config example: $CC_BIN $PC_CFLAGS main.c $PC_LIBS"
expect_prefix_lib "the pkg-config example" "$SCRATCH/example-pkgconfig/lensrt-example" LD_LIBRARY_PATH="$LIB"
step "run $SCRATCH/example-pkgconfig/lensrt-example (LD_LIBRARY_PATH=$LIB)"
LD_LIBRARY_PATH="$LIB" "$SCRATCH/example-pkgconfig/lensrt-example" ||
    die "pkg-config example: run (exit status $?)"

# ----------------------------------------------------------- 4. lensrt-psf -----
step "run $PREFIX/$BINDIR/lensrt-psf --help"
expect_prefix_lib "the installed lensrt-psf" "$PREFIX/$BINDIR/lensrt-psf"
"$PREFIX/$BINDIR/lensrt-psf" --help > "$SCRATCH/lensrt-psf-help.txt" 2>&1 ||
    { cat "$SCRATCH/lensrt-psf-help.txt" >&2; die "lensrt-psf --help (exit status $?)"; }
grep -q "usage: lensrt-psf" "$SCRATCH/lensrt-psf-help.txt" ||
    { cat "$SCRATCH/lensrt-psf-help.txt" >&2; die "lensrt-psf --help does not print its usage"; }

step "passed"
