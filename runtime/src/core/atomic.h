/* The few atomic operations host-scheduled tiles need (internal). C99 has no atomics:
 * GCC and Clang builtins, or MSVC's interlocked functions (not built here; each is a full
 * barrier, which is at least the ordering asked for). */
#ifndef LENSRT_ATOMIC_H
#define LENSRT_ATOMIC_H

#include <stdint.h>

#if defined(__GNUC__) || defined(__clang__)
/* *p += v; returns the value before. */
static inline uint32_t lensrt_atomic_add_u32(uint32_t *p, uint32_t v) { return __atomic_fetch_add(p, v, __ATOMIC_RELAXED); }
static inline void lensrt_atomic_add_u64(uint64_t *p, uint64_t v) { (void)__atomic_fetch_add(p, v, __ATOMIC_RELAXED); }
/* 1 for the one caller that turns *flag from 0 to 1, 0 for every other. */
static inline int lensrt_atomic_claim(int32_t *flag)
{
    int32_t expected = 0;
    return __atomic_compare_exchange_n(flag, &expected, 1, 0, __ATOMIC_ACQ_REL, __ATOMIC_ACQUIRE);
}
/* *p, and what was written before the release that stored it. */
static inline int32_t lensrt_atomic_load_acquire(const int32_t *p) { return __atomic_load_n(p, __ATOMIC_ACQUIRE); }
/* *p = v, after everything written before it. */
static inline void lensrt_atomic_store_release(int32_t *p, int32_t v) { __atomic_store_n(p, v, __ATOMIC_RELEASE); }
/* *p += v (acquire and release both); returns the value before. */
static inline int32_t lensrt_atomic_add_i32(int32_t *p, int32_t v) { return __atomic_fetch_add(p, v, __ATOMIC_ACQ_REL); }
/* 1 for the one caller that turns *p from `from` to `to`, 0 for every other. */
static inline int lensrt_atomic_cas_i32(int32_t *p, int32_t from, int32_t to)
{
    return __atomic_compare_exchange_n(p, &from, to, 0, __ATOMIC_ACQ_REL, __ATOMIC_ACQUIRE);
}
/* *p += v; returns the value after. */
static inline uint64_t lensrt_atomic_add_fetch_u64(uint64_t *p, uint64_t v) { return __atomic_add_fetch(p, v, __ATOMIC_RELAXED); }
#elif defined(_MSC_VER)
#include <intrin.h>
static inline uint32_t lensrt_atomic_add_u32(uint32_t *p, uint32_t v)
{
    return (uint32_t)_InterlockedExchangeAdd((volatile long *)p, (long)v);
}
static inline void lensrt_atomic_add_u64(uint64_t *p, uint64_t v)
{
    (void)_InterlockedExchangeAdd64((volatile __int64 *)p, (__int64)v);
}
static inline int lensrt_atomic_claim(int32_t *flag) { return _InterlockedCompareExchange((volatile long *)flag, 1, 0) == 0; }
static inline int32_t lensrt_atomic_load_acquire(const int32_t *p) { return (int32_t)_InterlockedOr((volatile long *)p, 0); }
static inline void lensrt_atomic_store_release(int32_t *p, int32_t v) { (void)_InterlockedExchange((volatile long *)p, (long)v); }
static inline int32_t lensrt_atomic_add_i32(int32_t *p, int32_t v) { return (int32_t)_InterlockedExchangeAdd((volatile long *)p, (long)v); }
static inline int lensrt_atomic_cas_i32(int32_t *p, int32_t from, int32_t to)
{
    return _InterlockedCompareExchange((volatile long *)p, (long)to, (long)from) == (long)from;
}
static inline uint64_t lensrt_atomic_add_fetch_u64(uint64_t *p, uint64_t v)
{
    return (uint64_t)_InterlockedExchangeAdd64((volatile __int64 *)p, (__int64)v) + v;
}
#else
#error "lensrt needs atomic operations for host-scheduled tiles (GCC/Clang builtins or MSVC)"
#endif

#endif /* LENSRT_ATOMIC_H */
