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

int lensrt_crc32_checksum_line(const char *text, size_t size, size_t *start, size_t *line, uint32_t *stated,
                               uint32_t *actual)
{
    static const char prefix[] = "checksum crc32 ";
    const size_t np = sizeof prefix - 1;
    size_t s = size, k, n = 1;
    uint32_t want = 0;
    int ok;
    // The last line's start: after the last '\n' before the final one
    if (size > 0 && text[size - 1] == '\n')
        for (s = size - 1; s > 0 && text[s - 1] != '\n'; s--) continue;
    for (k = 0; k < s; k++) n += text[k] == '\n';
    *start = s;
    *line = n;
    // Its form: the prefix, 8 lowercase hex digits, the final '\n'
    ok = s < size && size - s == np + 9;
    for (k = 0; ok && k < np; k++) ok = text[s + k] == prefix[k];
    for (k = 0; ok && k < 8; k++) {
        const char c = text[s + np + k];
        ok = (c >= '0' && c <= '9') || (c >= 'a' && c <= 'f');
        want = want << 4 | (uint32_t)(c <= '9' ? c - '0' : c - 'a' + 10);
    }
    if (!ok) return 0;
    // The stated CRC against every byte before the line
    *stated = want;
    *actual = lensrt_crc32(text, s);
    return 1;
}
