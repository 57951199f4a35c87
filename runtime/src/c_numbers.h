/* Numbers as text in the "C" locale, whatever the process's locale (internal).
 *
 * strtod and the printf family follow LC_NUMERIC: once a host program has called
 * setlocale(LC_ALL, "") under de_DE.UTF-8, "%g" writes 1,5 and strtod stops at the '.'
 * of "1.5". The library's text (lens tables, GLSL constants, EXR metadata, lens names
 * that phasor files hash, messages) must not change with the host's locale, so every
 * number the library parses or prints goes through these. setlocale() is no answer: it
 * changes the locale of the whole process and is not thread-safe. Instead the calling
 * thread alone is switched to the "C" locale (POSIX 2008 uselocale) for the one call,
 * and the thread's previous locale (its own, or the global one) is restored after.
 *
 * newlocale(LC_ALL_MASK, "C", 0) allocates nothing in glibc and musl (it returns their
 * static C locale object, and freelocale ignores it), so doing this per call is cheap.
 * If newlocale ever failed, the call falls back to the thread's locale.
 *
 * Header-only (static inline), so that sources compiled into tests without the library
 * (test_image_io's io sources) have them too. Needs _POSIX_C_SOURCE >= 200809L. */
#ifndef LENSRT_C_NUMBERS_H
#define LENSRT_C_NUMBERS_H

#include <errno.h>
#include <locale.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>

/* vsnprintf in the "C" locale. */
static inline int lensrt_vsnprintf_c(char *buf, size_t size, const char *fmt, va_list args)
{
    locale_t c_locale = newlocale(LC_ALL_MASK, "C", (locale_t)0);
    locale_t saved = c_locale ? uselocale(c_locale) : (locale_t)0;
    int n = vsnprintf(buf, size, fmt, args);
    if (c_locale) {
        uselocale(saved);
        freelocale(c_locale);
    }
    return n;
}

/* snprintf in the "C" locale. */
static inline int lensrt_snprintf_c(char *buf, size_t size, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 3, 4)))
#endif
    ;
static inline int lensrt_snprintf_c(char *buf, size_t size, const char *fmt, ...)
{
    va_list args;
    int n;
    va_start(args, fmt);
    n = lensrt_vsnprintf_c(buf, size, fmt, args);
    va_end(args);
    return n;
}

/* strtod in the "C" locale: '.' is the decimal point, whatever LC_NUMERIC says. errno is
 * what strtod left (kept across the locale switch back). */
static inline double lensrt_strtod_c(const char *s, char **end)
{
    locale_t c_locale = newlocale(LC_ALL_MASK, "C", (locale_t)0);
    locale_t saved = c_locale ? uselocale(c_locale) : (locale_t)0;
    double v = strtod(s, end);
    int err = errno;
    if (c_locale) {
        uselocale(saved);
        freelocale(c_locale);
    }
    errno = err;
    return v;
}

#endif /* LENSRT_C_NUMBERS_H */
