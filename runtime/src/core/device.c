/* The device table: the one core file that includes the devices' headers. */
#include "device.h"

#include "../cpu/cpu.h"
#ifdef LENSRT_GL
#include "../gl/gl_render.h"
#endif

const lensrt_device_ops *lensrt_device_find(int device)
{
    static const lensrt_device_ops *const devices[] = {
        &lensrt_device_cpu, /* LENSRT_DEVICE_CPU */
#ifdef LENSRT_GL
        &lensrt_device_gl,  /* LENSRT_DEVICE_GL */
#else
        NULL,
#endif
    };
    return device >= 0 && device < (int)(sizeof devices / sizeof devices[0]) ? devices[device] : NULL;
}
