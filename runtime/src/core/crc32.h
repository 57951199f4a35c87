/* CRC-32 (internal): ISO 3309 / ITU-T V.42, the checksum of PNG chunks and of zlib
 * (reflected polynomial 0xEDB88320, initial value and final XOR 0xFFFFFFFF). The PNG
 * writer checks its chunks with it, and coefficient tables end with it (version 4,
 * `checksum crc32 <hex>`). A CRC of degree 32 detects every error burst of up to 32 bits,
 * so every single-bit flip. The 256-entry table lives in the caller's state, not in a
 * global. */
#ifndef LENSRT_CRC32_H
#define LENSRT_CRC32_H

#include <stddef.h>
#include <stdint.h>

/* Fill the byte-at-a-time table. */
void lensrt_crc32_table(uint32_t table[256]);

/* Continue a CRC over `size` bytes: start from 0xFFFFFFFF, finish with ~state. */
uint32_t lensrt_crc32_update(const uint32_t table[256], uint32_t state, const void *data, size_t size);

/* The CRC-32 of one buffer (zlib's crc32(0, data, size)). */
uint32_t lensrt_crc32(const void *data, size_t size);

/* The checksum line that ends coefficient tables and PSF bank indexes:
 * `checksum crc32 <8 lowercase hex digits>\n` exactly, as the text's last line. Always
 * sets *start (where the last line starts: the end of the checksummed bytes) and *line
 * (its 1-based line number); returns 1 with *stated (the CRC the line states) and
 * *actual (the CRC-32 of the bytes before it) when the last line has that form, 0 when
 * not (a text cut short, or edited). Callers word their own messages. */
int lensrt_crc32_checksum_line(const char *text, size_t size, size_t *start, size_t *line, uint32_t *stated,
                               uint32_t *actual);

#endif
