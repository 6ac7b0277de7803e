// SPDX-License-Identifier: Apache-2.0
// Arrays the traversal reads at random (wide nodes, leaf triangle groups) on 2 MiB pages where
// the kernel gives them (issue 22). Incoherent rays land on a different 4 KiB page at nearly
// every node and leaf: a scene of 10^5-10^6 triangles keeps 10-60 MB of them, more pages than
// an Intel core's second-level TLB holds (1,536-2,048 entries), so the deep visits of a ray
// also wait for page walks (about 1.2 a ray in a simulated 1,536-entry TLB: docs/benchmarks.md,
// round 11), two-dimensional and several memory reads long inside a virtual machine. On 2 MiB
// pages the same bytes take a few dozen TLB entries. The bytes and their order are unchanged.
#pragma once

#include <cstddef>
#include <new>
#include <vector>

namespace clastrace::engine::detail {

// Arrays of at least this many bytes are mapped on their own (huge_page_allocate); smaller ones
// come from operator new (a huge page would hold mostly nothing).
inline constexpr size_t kHugePageArrayBytes = size_t(2) << 20;

// `bytes` (>= kHugePageArrayBytes) of zeroed memory starting on a 2 MiB boundary, marked for
// transparent huge pages (madvise MADV_HUGEPAGE: taken where the kernel's setting is "always"
// or "madvise", a hint otherwise). The mapping ends at `bytes` rounded up to 4 KiB, so a tail
// short of a whole huge page stays on 4 KiB pages and nothing is wasted. Throws
// std::bad_alloc when the address space is exhausted.
void* huge_page_allocate(size_t bytes);
// Gives back what huge_page_allocate(bytes) returned.
void huge_page_free(void* p, size_t bytes);

// std::allocator's contract, large arrays from huge_page_allocate (aligned to 2 MiB, which
// covers any alignment of T), small ones from the aligned operator new.
template <class T>
struct HugePageAllocator {
    using value_type = T;
    HugePageAllocator() = default;
    template <class U>
    HugePageAllocator(const HugePageAllocator<U>&) {}
    T* allocate(size_t n) {
        if (n > size_t(-1) / sizeof(T)) throw std::bad_array_new_length();
        const size_t bytes = n * sizeof(T);
        if (bytes >= kHugePageArrayBytes) return static_cast<T*>(huge_page_allocate(bytes));
        return static_cast<T*>(::operator new(bytes, std::align_val_t(alignof(T))));
    }
    void deallocate(T* p, size_t n) {
        const size_t bytes = n * sizeof(T);
        if (bytes >= kHugePageArrayBytes)
            huge_page_free(p, bytes);
        else
            ::operator delete(p, std::align_val_t(alignof(T)));
    }
    template <class U>
    bool operator==(const HugePageAllocator<U>&) const {
        return true;
    }
    template <class U>
    bool operator!=(const HugePageAllocator<U>&) const {
        return false;
    }
};

// A traversal array: a std::vector whose large buffers lie on huge pages.
template <class T>
using HugePageVector = std::vector<T, HugePageAllocator<T>>;

}  // namespace clastrace::engine::detail
