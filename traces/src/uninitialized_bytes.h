// SPDX-License-Identifier: Apache-2.0
// Byte buffers whose growth leaves the new bytes uninitialized. The writer's chunk buffers,
// streams and compressed payloads are written over whole before anything reads them, so
// value-initializing them first (what std::vector<uint8_t>::resize does) would be one more pass
// over every chunk, and on fresh pages a fault for each.
#pragma once

#include <cstdint>
#include <memory>
#include <new>
#include <utility>
#include <vector>

namespace clastrace::traces::format {

template <class T>
struct UninitializedAllocator : std::allocator<T> {
    template <class U>
    struct rebind {
        using other = UninitializedAllocator<U>;  // NOLINT(readability-identifier-naming): std's
    };
    UninitializedAllocator() = default;
    template <class U>
    UninitializedAllocator(const UninitializedAllocator<U>&) noexcept {}
    template <class U>
    void construct(U* p) noexcept {
        ::new (static_cast<void*>(p)) U;
    }
    template <class U, class... Args>
    void construct(U* p, Args&&... args) {
        ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
    }
};

using UninitializedBytes = std::vector<uint8_t, UninitializedAllocator<uint8_t>>;

}  // namespace clastrace::traces::format
