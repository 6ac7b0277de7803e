// SPDX-License-Identifier: Apache-2.0
// LD_PRELOAD shim for the capture tests: writes to the file named by CLASTRACE_TEST_FULL_PATH
// fail with ENOSPC once CLASTRACE_TEST_FULL_AFTER bytes went to it, as on a disk that fills up
// while the trace grows (no root needed, unlike a small filesystem).
#include <dlfcn.h>
#include <sys/uio.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>

namespace {

std::atomic<unsigned long long> written{0};

bool isTarget(int fd) {
    const char* target = std::getenv("CLASTRACE_TEST_FULL_PATH");
    if (!target) return false;
    char link[64], path[4096];
    std::snprintf(link, sizeof link, "/proc/self/fd/%d", fd);
    const ssize_t n = readlink(link, path, sizeof path - 1);
    if (n <= 0) return false;
    path[n] = 0;
    return std::strcmp(path, target) == 0;
}

}  // namespace

extern "C" ssize_t writev(int fd, const struct iovec* iov, int count) {
    using Writev = ssize_t (*)(int, const struct iovec*, int);
    static Writev next = reinterpret_cast<Writev>(dlsym(RTLD_NEXT, "writev"));
    if (isTarget(fd)) {
        const char* after = std::getenv("CLASTRACE_TEST_FULL_AFTER");
        const unsigned long long limit = after ? std::strtoull(after, nullptr, 10) : 0;
        size_t total = 0;
        for (int i = 0; i < count; ++i) total += iov[i].iov_len;
        if (written + total > limit) {
            errno = ENOSPC;
            return -1;
        }
        written += total;
    }
    return next(fd, iov, count);
}
