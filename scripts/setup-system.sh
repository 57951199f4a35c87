#!/usr/bin/env bash
# Install the Debian packages the toolkit needs, only those that are missing.
# Idempotent; uses sudo when not root. Debian 12 (bookworm) is the reference system.
set -euo pipefail

need=()
have() { dpkg-query -W -f='${Status}' "$1" 2>/dev/null | grep -q "install ok installed"; }

# python3 with venv and ensurepip (the virtualenv holds the pinned Python packages)
for pkg in python3 python3-venv; do
  have "$pkg" || need+=("$pkg")
done
# C toolchain and CMake for the runtime
for pkg in build-essential cmake; do
  have "$pkg" || need+=("$pkg")
done
# OpenEXRCore for the runtime's EXR output, pkg-config for the installed-package test
for pkg in libopenexr-dev pkg-config; do
  have "$pkg" || need+=("$pkg")
done
# glslangValidator, so the tests can compile the generated GLSL
for pkg in glslang-tools; do
  have "$pkg" || need+=("$pkg")
done
# The GL path: EGL and GL headers to build it (no GL library is linked); at run time
# libEGL with Mesa's EGL vendor and llvmpipe (a GL 4.5 device on any CPU), and GLFW with
# a virtual X server for the GLFW fallback's tests
for pkg in libegl-dev libgl-dev libegl1 libegl-mesa0 libgl1-mesa-dri libglfw3 xvfb xauth; do
  have "$pkg" || need+=("$pkg")
done
# clang with its sanitizer and libFuzzer runtimes, for tests/fuzz/run.sh
for pkg in clang libclang-rt-14-dev; do
  have "$pkg" || need+=("$pkg")
done
# A comma-decimal locale for tests/runtime/test_locale.c (lensrt must read and write
# numbers the same under de_DE's LC_NUMERIC): the locale sources, compiled below
for pkg in locales; do
  have "$pkg" || need+=("$pkg")
done

SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  SUDO="sudo"
fi
if [ ${#need[@]} -gt 0 ]; then
  if ! command -v apt-get >/dev/null 2>&1; then
    echo "setup: missing packages ${need[*]} and no apt-get: install them by hand" >&2
    exit 1
  fi
  echo "setup: installing ${need[*]}" >&2
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${need[@]}"
fi

# de_DE.UTF-8, only when missing (`locale -a` lists it as de_DE.utf8)
if ! locale -a 2>/dev/null | grep -qix 'de_DE\.utf-\?8'; then
  echo "setup: generating the locale de_DE.UTF-8" >&2
  $SUDO localedef -i de_DE -f UTF-8 de_DE.UTF-8
fi
