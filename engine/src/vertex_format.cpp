// SPDX-License-Identifier: Apache-2.0
#include "clastrace/engine/vertex_format.h"

#include <bit>
#include <cmath>
#include <cstring>

namespace clastrace::engine {

VertexFormatInfo vertex_format_info(uint32_t format) {
    switch (format) {
    case VK_FORMAT_R32G32B32_SFLOAT: return {true, 12, 4, 3};
    case VK_FORMAT_R32G32B32A32_SFLOAT: return {true, 16, 4, 3};
    case VK_FORMAT_R32G32_SFLOAT: return {true, 8, 4, 2};
    case VK_FORMAT_R16G16B16A16_SFLOAT: return {true, 8, 2, 3};
    case VK_FORMAT_R16G16B16_SFLOAT: return {true, 6, 2, 3};
    case VK_FORMAT_R16G16_SFLOAT: return {true, 4, 2, 2};
    case VK_FORMAT_R16G16B16A16_SNORM: return {true, 8, 2, 3};
    case VK_FORMAT_R16G16_SNORM: return {true, 4, 2, 2};
    case VK_FORMAT_R16G16B16A16_UNORM: return {true, 8, 2, 3};
    case VK_FORMAT_R16G16_UNORM: return {true, 4, 2, 2};
    case VK_FORMAT_R8G8B8A8_SNORM: return {true, 4, 1, 3};
    case VK_FORMAT_R8G8_SNORM: return {true, 2, 1, 2};
    case VK_FORMAT_R8G8B8A8_UNORM: return {true, 4, 1, 3};
    case VK_FORMAT_R8G8_UNORM: return {true, 2, 1, 2};
    case VK_FORMAT_A2B10G10R10_UNORM_PACK32: return {true, 4, 4, 3};
    default: return {};
    }
}

uint32_t vertex_format_bytes(VkFormat format) {
    return format == VK_FORMAT_R16G16B16_SNORM ? 6 : vertex_format_info(format).size;
}

uint32_t index_type_bytes(VkIndexType type) {
    switch (type) {
    case VK_INDEX_TYPE_UINT16: return 2;
    case VK_INDEX_TYPE_UINT32: return 4;
    case VK_INDEX_TYPE_UINT8_EXT: return 1;
    default: return 0;
    }
}

namespace {

float half_to_float(uint16_t h) {
    const uint32_t sign = uint32_t(h & 0x8000u) << 16;
    const uint32_t exp = (h >> 10) & 0x1Fu;
    uint32_t mant = h & 0x3FFu;
    uint32_t bits;
    if (exp == 0) {
        if (mant == 0) {
            bits = sign;
        } else {  // subnormal half: renormalize
            int e = -1;
            do {
                ++e;
                mant <<= 1;
            } while ((mant & 0x400u) == 0);
            bits = sign | (uint32_t(127 - 15 - e) << 23) | ((mant & 0x3FFu) << 13);
        }
    } else if (exp == 0x1F) {
        bits = sign | 0x7F800000u | (mant << 13);
    } else {
        bits = sign | ((exp + 127 - 15) << 23) | (mant << 13);
    }
    return std::bit_cast<float>(bits);
}

template <class T>
T load(const std::byte* p) {
    T v;
    std::memcpy(&v, p, sizeof v);
    return v;
}

float snorm(int32_t v, int bits) {
    const float m = float((1 << (bits - 1)) - 1);
    const float f = float(v) / m;
    return f < -1.0f ? -1.0f : f;
}
float unorm(uint32_t v, int bits) { return float(v) / float((1u << bits) - 1u); }

}  // namespace

void decode_vertex(VkFormat format, const std::byte* src, float xyz[3]) {
    xyz[2] = 0.0f;
    switch (format) {
    case VK_FORMAT_R32G32B32_SFLOAT:
    case VK_FORMAT_R32G32B32A32_SFLOAT: std::memcpy(xyz, src, 12); return;
    case VK_FORMAT_R32G32_SFLOAT: std::memcpy(xyz, src, 8); return;
    case VK_FORMAT_R16G16B16A16_SFLOAT:
    case VK_FORMAT_R16G16B16_SFLOAT:
        for (int i = 0; i < 3; ++i) xyz[i] = half_to_float(load<uint16_t>(src + 2 * i));
        return;
    case VK_FORMAT_R16G16_SFLOAT:
        for (int i = 0; i < 2; ++i) xyz[i] = half_to_float(load<uint16_t>(src + 2 * i));
        return;
    case VK_FORMAT_R16G16B16A16_SNORM:
        for (int i = 0; i < 3; ++i) xyz[i] = snorm(load<int16_t>(src + 2 * i), 16);
        return;
    case VK_FORMAT_R16G16_SNORM:
        for (int i = 0; i < 2; ++i) xyz[i] = snorm(load<int16_t>(src + 2 * i), 16);
        return;
    case VK_FORMAT_R16G16B16A16_UNORM:
        for (int i = 0; i < 3; ++i) xyz[i] = unorm(load<uint16_t>(src + 2 * i), 16);
        return;
    case VK_FORMAT_R16G16_UNORM:
        for (int i = 0; i < 2; ++i) xyz[i] = unorm(load<uint16_t>(src + 2 * i), 16);
        return;
    case VK_FORMAT_R8G8B8A8_SNORM:
        for (int i = 0; i < 3; ++i) xyz[i] = snorm(load<int8_t>(src + i), 8);
        return;
    case VK_FORMAT_R8G8_SNORM:
        for (int i = 0; i < 2; ++i) xyz[i] = snorm(load<int8_t>(src + i), 8);
        return;
    case VK_FORMAT_R8G8B8A8_UNORM:
        for (int i = 0; i < 3; ++i) xyz[i] = unorm(load<uint8_t>(src + i), 8);
        return;
    case VK_FORMAT_R8G8_UNORM:
        for (int i = 0; i < 2; ++i) xyz[i] = unorm(load<uint8_t>(src + i), 8);
        return;
    case VK_FORMAT_A2B10G10R10_UNORM_PACK32: {
        const uint32_t w = load<uint32_t>(src);
        for (int i = 0; i < 3; ++i) xyz[i] = unorm((w >> (10 * i)) & 0x3FFu, 10);
        return;
    }
    default: xyz[0] = xyz[1] = xyz[2] = std::nanf(""); return;
    }
}

float truncate_position(float value, uint32_t bits) {
    if (bits == 0) return value;
    if (bits >= 32) return 0.0f;
    const uint32_t mask = ~((1u << bits) - 1u);
    return std::bit_cast<float>(std::bit_cast<uint32_t>(value) & mask);
}

}  // namespace clastrace::engine
