// SPDX-License-Identifier: Apache-2.0
// The engine's byte formats for a CLAS and a cluster template (docs/engine-formats.md).
//
// An object is position independent: every offset inside it is relative to its first
// byte, so a plain copy moves it. Its header alone says what it is and how big it is,
// which is what BLAS builds and moves read at an arbitrary device address.
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>

namespace clastrace::engine {

inline constexpr uint32_t kObjectMagic = 0x53414C43u;  // "CLAS" read as little-endian bytes
inline constexpr uint8_t kFormatVersion = 1;

enum class ObjectType : uint8_t {
    kTriangleCluster = 1,          // a CLAS (built or instantiated)
    kTriangleClusterTemplate = 2,  // a cluster template
    kClustersBottomLevel = 3,      // reserved for the bottom-level issue
};

// header_flags bits
inline constexpr uint16_t kHasTriangleData = 0x1;     // per-triangle geometry index+flags section
inline constexpr uint16_t kHasOpacityMicromap = 0x2;  // OMM section
inline constexpr uint16_t kHasPositions = 0x4;    // positions section present (templates may omit)
inline constexpr uint16_t kHasBoundsLimit = 0x8;  // template: instantiation bounding-box limit
inline constexpr uint16_t kHasTriangleOrder = 0x10;  // original-triangle-index section present
inline constexpr uint16_t kUnboundedNodes =
    0x20;  // node boxes not quantizable: every node box is infinite
inline constexpr uint16_t kHasNaNTriangles = 0x40;  // informational: some triangles are inactive

// 96 bytes, little-endian, at offset 0 of every engine object.
struct ObjectHeader {
    uint32_t magic;          // kObjectMagic
    uint8_t object_type;     // ObjectType
    uint8_t format_version;  // kFormatVersion
    uint16_t header_flags;   // k* flags above
    uint32_t object_size;    // bytes of the whole object, header included
    uint32_t cluster_id;     // clusterID (templates: before clusterIdOffset)
    uint16_t triangle_count;
    uint16_t vertex_count;
    uint8_t position_truncate_bits;
    uint8_t position_bits;  // 32 - position_truncate_bits: bits stored per coordinate
    uint8_t cluster_flags;  // VkClusterAccelerationStructureClusterFlagsNV
    uint8_t reserved_u8;
    uint32_t base_geometry_index_and_flags;  // geometryIndex:24 | reserved:5 | geometryFlags:3
    float bounds_min[3];  // AABB of the active (non-NaN) triangles' truncated positions
    float bounds_max[3];
    uint32_t positions_offset;  // packed coordinates, 0 when absent
    uint32_t indices_offset;    // triangle_count*3 uint8 local vertex indices (BVH order)
    uint32_t
        triangle_data_offset;  // triangle_count uint32 geometryIndexAndFlags (BVH order), 0 when absent
    uint32_t
        triangle_order_offset;  // triangle_count uint8 original triangle index (BVH order), 0 when identity
    uint32_t nodes_offset;         // node_count BvhNode (root first), 0 when node_count == 0
    uint32_t omm_offset;           // OpacityMicromapSection, 0 when absent
    uint32_t vertex_format;        // VkFormat of the input (10508 compares it)
    uint32_t bounds_limit_offset;  // template: 6 floats (min xyz, max xyz), 0 when absent
    uint32_t max_geometry_index;  // highest geometry index of any triangle (before instance offset)
    uint16_t node_count;          // BVH nodes (0 when no triangle is active)
    uint16_t reserved1;
    uint32_t reserved2;
};
static_assert(sizeof(ObjectHeader) == 96);

// BVH node, 8 bytes. Boxes are quantized conservatively to 8 bits per bound inside the
// header's bounds. link: bit 15 set = leaf, bits 0-7 first triangle (BVH order), bits
// 8-9 triangle count - 1; bit 15 clear = interior, bits 0-9 index of the left child (the
// right child follows it).
struct BvhNode {
    uint8_t qmin[3];
    uint8_t qmax[3];
    uint16_t link;
};
inline constexpr uint16_t kLeafBit = 0x8000;
static_assert(sizeof(BvhNode) == 8);
inline constexpr uint32_t kMaxLeafSize = 4;

// Present only when opacityMicromapArray != 0: recorded for analysis, not traced.
struct OpacityMicromapSection {
    uint64_t opacity_micromap_array;
    uint32_t index_type;  // VkClusterAccelerationStructureIndexFormatFlagBitsNV
    uint32_t reserved;
    // followed by triangle_count int32 indices (BVH order)
};
static_assert(sizeof(OpacityMicromapSection) == 16);

// Reads and checks the header of an object: magic, version, type, and that every
// section lies inside object_size and inside `bytes`. Returns an explanation on failure.
struct HeaderCheck {
    std::optional<ObjectHeader> header;
    std::string error;  // empty when header is set
};
HeaderCheck read_object_header(std::span<const std::byte> bytes);

// Size of the object starting at `bytes` from its header alone (0 if not an object).
uint32_t object_size_from_header(std::span<const std::byte> bytes);

// Decoded view of a cluster object (for tests, analysis and next-level builders).
struct DecodedTriangle {
    float v[3][3];
    uint32_t original_index;  // triangle index as the app numbered it
    uint32_t geometry_index_and_flags;
    uint8_t local_indices[3];
};
// The decoded triangle at BVH position `i`, and vertex `v`'s stored position.
DecodedTriangle decode_triangle(std::span<const std::byte> object, const ObjectHeader& h,
                                uint32_t i);
void decode_position(std::span<const std::byte> object, const ObjectHeader& h, uint32_t vertex,
                     float xyz[3]);

}  // namespace clastrace::engine
