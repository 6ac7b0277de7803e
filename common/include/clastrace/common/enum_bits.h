// SPDX-License-Identifier: Apache-2.0
// The 32 bits of a Vulkan enum field, read and written without loading or storing the enum.
//
// Vulkan's C enums have no fixed underlying type, so in C++ their values are those their
// enumerators need: 0..0x7FFFFFFF (each has a *_MAX_ENUM of 0x7FFFFFFF). An application, or a
// trace, may still hold any 32 bits in such a field, and loading 0x80000000 or more as the
// enum is undefined (UBSan's -fsanitize=enum stops there). Such fields are carried by their
// bits until a check has found the value valid; only then is the field read as the enum.
#pragma once

#include <cstdint>
#include <cstring>
#include <type_traits>

namespace clastrace::common {

template <class Enum>
uint32_t enum_bits(const Enum& field) {
    static_assert(std::is_enum_v<Enum> && sizeof(Enum) == sizeof(uint32_t));
    uint32_t bits;
    std::memcpy(&bits, &field, sizeof bits);
    return bits;
}

template <class Enum>
void set_enum_bits(Enum& field, uint32_t bits) {
    static_assert(std::is_enum_v<Enum> && sizeof(Enum) == sizeof(uint32_t));
    std::memcpy(&field, &bits, sizeof bits);
}

}  // namespace clastrace::common
