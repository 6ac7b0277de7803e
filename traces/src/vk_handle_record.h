// SPDX-License-Identifier: Apache-2.0
// A Vulkan handle as a record field: non-dispatchable handles are pointers on 64-bit targets
// and uint64_t on 32-bit ones, and both are stored as uint64.
#pragma once

#include <cstdint>
#include <type_traits>

namespace clastrace::traces::detail {

template <class Handle>
uint64_t handle_to_record(Handle handle) {
    if constexpr (std::is_pointer_v<Handle>)
        return reinterpret_cast<uintptr_t>(handle);
    else
        return uint64_t(handle);
}

template <class Handle>
Handle handle_from_record(uint64_t value) {
    if constexpr (std::is_pointer_v<Handle>)
        return reinterpret_cast<Handle>(uintptr_t(value));
    else
        return Handle(value);
}

}  // namespace clastrace::traces::detail
