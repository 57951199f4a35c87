/* The CPU device (internal): OpenMP threads over pixel groups, the SIMD splat kernel. */
#ifndef LENSRT_CPU_H
#define LENSRT_CPU_H

#include "../core/device.h"

extern const lensrt_device_ops lensrt_device_cpu;

#endif /* LENSRT_CPU_H */
