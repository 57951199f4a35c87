/* Atomic writes (internal): a unique temporary file next to the target, renamed over it
 * only when complete. Used by the EXR, PNG and phasor-sum writers.
 *
 * The target must be a regular file or absent: symbolic links, directories, device
 * nodes, FIFOs and sockets are refused (a rename would replace them with a regular
 * file). The temporary file takes the target's permission bits. Temporaries of our own
 * naming (`<target>.tmp-<pid>-<clock>-<attempt>`) whose process is gone (killed during
 * a write) are removed when the same target is written next. */
#ifndef _POSIX_C_SOURCE
#define _POSIX_C_SOURCE 200809L /* open, getpid, clock_gettime, lstat, kill, opendir */
#endif

#include "image_io.h"

#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/types.h>
#include <time.h>
#include <unistd.h>

const char *lensrt_target_refusal(const char *path)
{
    struct stat st;
    // Absent (or not inspectable: the open will say why) is fine, and so is a regular file
    if (lstat(path, &st) != 0 || S_ISREG(st.st_mode))
        return NULL;
    if (S_ISLNK(st.st_mode))
        return "is a symbolic link; lensrt replaces files by renaming and does not follow links: "
               "give the link's target path";
    if (S_ISDIR(st.st_mode))
        return "is a directory, not a file";
    if (S_ISCHR(st.st_mode) || S_ISBLK(st.st_mode))
        return "is a device node; lensrt writes regular files only";
    if (S_ISFIFO(st.st_mode))
        return "is a FIFO; lensrt writes regular files only";
    return "is not a regular file; lensrt writes regular files only";
}

/* Remove `<path>.tmp-<pid>-<clock>-<attempt>` files left by processes that no longer run
 * (kill -9 during a write). Files of live processes (and this one) are left alone.
 * `name` (strlen(path) + 64 bytes) is scratch space for the folder and file names. */
static void remove_stale(const char *path, char *name)
{
    const char *slash = strrchr(path, '/');
    const char *base = slash ? slash + 1 : path;
    size_t dir_len = slash ? (size_t)(slash - path) + 1 : 0, base_len = strlen(base);
    DIR *dir;
    struct dirent *e;
    // Step 1: the folder (".", "/" or the prefix up to the last slash)
    if (dir_len == 0)
        strcpy(name, ".");
    else {
        memcpy(name, path, dir_len);
        name[dir_len] = '\0';
    }
    dir = opendir(name);
    // Step 2: entries named exactly `<base>.tmp-<pid>-<digits>-<digits>` of a dead pid
    while (dir && (e = readdir(dir)) != NULL) {
        const char *p = e->d_name;
        char *end;
        long pid;
        if (strncmp(p, base, base_len) != 0 || strncmp(p + base_len, ".tmp-", 5) != 0 ||
            strlen(p) >= base_len + 60)
            continue;
        p += base_len + 5;
        pid = strtol(p, &end, 10);
        if (end == p || *end != '-' || pid <= 0 || (pid_t)pid == getpid())
            continue;
        p = end + 1;
        (void)strtol(p, &end, 10);
        if (end == p || *end != '-')
            continue;
        p = end + 1;
        (void)strtol(p, &end, 10);
        if (end == p || *end != '\0')
            continue;
        // kill(pid, 0) fails with ESRCH only when no such process exists
        if (kill((pid_t)pid, 0) == 0 || errno != ESRCH)
            continue;
        memcpy(name + dir_len, e->d_name, strlen(e->d_name) + 1);
        (void)unlink(name);
    }
    if (dir)
        closedir(dir);
}

int lensrt_open_temporary(const lensrt_allocator *allocator, const char *path, char **out_name,
                          int *out_errno)
{
    size_t size = strlen(path) + 64; /* room for ".tmp-<pid>-<clock>-<attempt>" */
    char *name = (char *)allocator->alloc_fn(size, allocator->user_data);
    struct timespec now;
    struct stat st;
    int attempt, keep_mode;
    *out_name = NULL;
    *out_errno = ENOMEM;
    if (!name)
        return -1;
    // The target's permission bits, kept by the replacement; leftovers of killed writers go
    keep_mode = stat(path, &st) == 0 && S_ISREG(st.st_mode);
    remove_stale(path, name);
    if (clock_gettime(CLOCK_REALTIME, &now) != 0)
        now.tv_nsec = 0;
    // O_EXCL: two writers (threads, processes) never share a temporary file
    for (attempt = 0; attempt < 100; ++attempt) {
        int fd;
        snprintf(name, size, "%s.tmp-%ld-%ld-%d", path, (long)getpid(), (long)now.tv_nsec, attempt);
        fd = open(name, O_WRONLY | O_CREAT | O_EXCL, 0666);
        if (fd >= 0) {
            if (keep_mode && fchmod(fd, st.st_mode & 07777) != 0) {
                *out_errno = errno;
                close(fd);
                remove(name);
                break;
            }
            *out_name = name;
            *out_errno = 0;
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
