/* Atomic writes (internal): a unique temporary file next to the target, renamed over it
 * only when complete. Used by the EXR, PNG and phasor-sum writers. */
#ifndef _POSIX_C_SOURCE
#define _POSIX_C_SOURCE 200809L /* open, getpid, clock_gettime */
#endif

#include "image_io.h"

#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

int lensrt_open_temporary(const lensrt_allocator *allocator, const char *path, char **out_name,
                          int *out_errno)
{
    size_t size = strlen(path) + 64; /* room for ".tmp-<pid>-<clock>-<attempt>" */
    char *name = (char *)allocator->alloc_fn(size, allocator->user_data);
    struct timespec now;
    int attempt;
    *out_name = NULL;
    *out_errno = ENOMEM;
    if (!name)
        return -1;
    if (clock_gettime(CLOCK_REALTIME, &now) != 0)
        now.tv_nsec = 0;
    // O_EXCL: two writers (threads, processes) never share a temporary file
    for (attempt = 0; attempt < 100; ++attempt) {
        int fd;
        snprintf(name, size, "%s.tmp-%ld-%ld-%d", path, (long)getpid(), (long)now.tv_nsec, attempt);
        fd = open(name, O_WRONLY | O_CREAT | O_EXCL, 0666);
        if (fd >= 0) {
            *out_name = name;
            return fd;
        }
        *out_errno = errno;
        if (errno != EEXIST)
            break;
    }
    allocator->free_fn(name, allocator->user_data);
    return -1;
}

FILE *lensrt_fopen_temporary(const lensrt_allocator *allocator, const char *path, char **out_name, int *out_errno)
{
    int fd = lensrt_open_temporary(allocator, path, out_name, out_errno);
    FILE *file;
    if (fd < 0)
        return NULL;
    file = fdopen(fd, "wb");
    if (!file) {
        *out_errno = errno;
        close(fd);
        remove(*out_name);
        allocator->free_fn(*out_name, allocator->user_data);
        *out_name = NULL;
    }
    return file;
}
