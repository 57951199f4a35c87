/* The few atomic operations host-scheduled tiles need (internal). C99 has no atomics:
 * GCC and Clang builtins, or MSVC's interlocked functions (not built here). */
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
#else
#error "lensrt needs atomic operations for host-scheduled tiles (GCC/Clang builtins or MSVC)"
#endif

#endif /* LENSRT_ATOMIC_H */
