// SPDX-License-Identifier: Apache-2.0
// Mappings for traversal arrays on transparent huge pages (huge_pages.h).
#include "huge_pages.h"

#include <cstdint>

#include <sys/mman.h>

namespace clastrace::engine::detail {
namespace {

constexpr uintptr_t kHugePage = uintptr_t(2) << 20;
constexpr size_t kSmallPage = size_t(4) << 10;

size_t mapped_bytes(size_t bytes) { return (bytes + kSmallPage - 1) & ~(kSmallPage - 1); }

}  // namespace

void* huge_page_allocate(size_t bytes) {
    const size_t size = mapped_bytes(bytes);
    // One huge page more than needed, then the parts before the first 2 MiB boundary and past
    // `size` unmapped: mmap itself only promises 4 KiB alignment.
    void* raw =
        mmap(nullptr, size + kHugePage, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    if (raw == MAP_FAILED) throw std::bad_alloc();
    const uintptr_t begin = reinterpret_cast<uintptr_t>(raw);
    const uintptr_t aligned = (begin + kHugePage - 1) & ~(kHugePage - 1);
    if (aligned != begin) munmap(raw, aligned - begin);
    const uintptr_t end = begin + size + kHugePage;
    if (end != aligned + size)
        munmap(reinterpret_cast<void*>(aligned + size), end - aligned - size);
    void* p = reinterpret_cast<void*>(aligned);
    // Before the first write, so that the first touch of each 2 MiB range faults in a huge page.
    // Refused (a kernel without THP): 4 KiB pages, as before.
    madvise(p, size, MADV_HUGEPAGE);
    return p;
}

void huge_page_free(void* p, size_t bytes) {
    if (p) munmap(p, mapped_bytes(bytes));
}

}  // namespace clastrace::engine::detail
