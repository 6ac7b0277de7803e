// SPDX-License-Identifier: Apache-2.0
// An LD_PRELOAD shim that refuses to make memory read-only (mprotect with PROT_READ alone fails
// with EACCES), as a driver's mapping of device memory may: the layer's page guard must then
// fall back to hashing (capture/README.md, "Host writes").
#include <cerrno>
#include <cstddef>

#include <dlfcn.h>
#include <sys/mman.h>

extern "C" int mprotect(void* address, size_t length, int protection) {
    if (protection == PROT_READ) {
        errno = EACCES;
        return -1;
    }
    using Next = int (*)(void*, size_t, int);
    static const Next kNext = reinterpret_cast<Next>(dlsym(RTLD_NEXT, "mprotect"));
    return kNext(address, length, protection);
}
