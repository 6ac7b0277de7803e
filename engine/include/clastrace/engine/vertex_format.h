// SPDX-License-Identifier: Apache-2.0
// Vertex formats a cluster input may use, decoded to float positions.
//
// VUID-VkClusterAccelerationStructureTriangleClusterInputNV-vertexFormat-10439 allows any
// format with VK_FORMAT_FEATURE_ACCELERATION_STRUCTURE_VERTEX_BUFFER_BIT_KHR. The engine
// decodes every format that feature is defined for: the mandatory ones (R32G32_SFLOAT,
// R32G32B32_SFLOAT, R16G16_SFLOAT, R16G16B16A16_SFLOAT, R16G16_SNORM, R16G16B16A16_SNORM)
// and the optional ones drivers report (R16G16B16_SFLOAT, R16G16_UNORM,
// R16G16B16A16_UNORM, R8G8_SNORM, R8G8B8A8_SNORM, R8G8_UNORM, R8G8B8A8_UNORM,
// A2B10G10R10_UNORM_PACK32, R32G32B32A32_SFLOAT). Two-component formats give z = 0; the
// fourth component is ignored. Truncation (positionTruncateBitCount) applies afterwards,
// to the 32-bit float pattern of each decoded coordinate.
#pragma once

#include "clastrace/vk_cluster_abi.h"

#include <cstddef>
#include <cstdint>

namespace clastrace::engine {

struct VertexFormatInfo {
    bool supported = false;
    uint32_t size = 0;            // bytes per vertex (tightly packed stride)
    uint32_t component_size = 0;  // bytes of one component (10495/10504 stride rule)
    uint32_t components = 0;      // position components read (2 or 3)
};

// `format` is the field's 32 bits (common/enum_bits.h): a trace may hold a value no VkFormat has.
VertexFormatInfo vertex_format_info(uint32_t format);

// Bytes of one tightly packed vertex of `format` for any build that may name it: the formats
// above and the NV-only R16G16B16_SNORM (VUID-VkGeometryTrianglesNV-vertexFormat-02430); 0 for
// a format no build decodes. What capture saves a vertex by, whichever rule the build breaks.
uint32_t vertex_format_bytes(VkFormat format);

// Bytes of one index of `type`; 0 for VK_INDEX_TYPE_NONE_KHR (no index buffer) and types no
// build names. UINT8 counts (1): no build allows it, but capture keeps its bytes for replay
// to name the rule.
uint32_t index_type_bytes(VkIndexType type);

// Decodes one vertex at `src` (format size bytes, any alignment) into xyz.
void decode_vertex(VkFormat format, const std::byte* src, float xyz[3]);

// Zeroes the low `bits` bits (0..32) of a float's bit pattern, as the GPU does.
float truncate_position(float value, uint32_t bits);

}  // namespace clastrace::engine
