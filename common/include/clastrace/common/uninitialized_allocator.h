// SPDX-License-Identifier: Apache-2.0
// An allocator whose value-less construct leaves an element of an implicit-lifetime type
// (trivially copyable and destructible: its storage already holds one) uninitialized, default
// member initializers included. Arrays that are
// written over whole before anything reads them (decompressed chunks, the writer's streams, the
// NV build's gathered records) grow with resize() without a first pass of zeros over every byte,
// and on fresh pages without a fault for each.
#pragma once

#include <cstdint>
#include <memory>
#include <new>
#include <type_traits>
#include <utility>
#include <vector>

namespace clastrace::common {

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
    void construct(U* p) noexcept(std::is_nothrow_default_constructible_v<U>) {
        if constexpr (!std::is_trivially_copyable_v<U> || !std::is_trivially_destructible_v<U>)
            ::new (static_cast<void*>(p)) U;
    }
    template <class U, class... Args>
    void construct(U* p, Args&&... args) {
        ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
    }
};

// Bytes that grow uninitialized.
using UninitializedBytes = std::vector<uint8_t, UninitializedAllocator<uint8_t>>;

}  // namespace clastrace::common
