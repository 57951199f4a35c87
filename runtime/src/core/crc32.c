/* CRC-32 (crc32.h). */
#include "crc32.h"

void lensrt_crc32_table(uint32_t table[256])
{
    uint32_t n;
    for (n = 0; n < 256; ++n) {
        uint32_t c = n;
        int k;
        for (k = 0; k < 8; ++k)
            c = (c & 1u) ? 0xEDB88320u ^ (c >> 1) : c >> 1;
        table[n] = c;
    }
}

uint32_t lensrt_crc32_update(const uint32_t table[256], uint32_t state, const void *data, size_t size)
{
    const unsigned char *p = data;
    size_t i;
    for (i = 0; i < size; ++i)
        state = table[(state ^ p[i]) & 0xFFu] ^ (state >> 8);
    return state;
}

uint32_t lensrt_crc32(const void *data, size_t size)
{
    uint32_t table[256];
    lensrt_crc32_table(table);
    return ~lensrt_crc32_update(table, 0xFFFFFFFFu, data, size);
}
