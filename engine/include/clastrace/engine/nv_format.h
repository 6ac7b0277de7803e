// SPDX-License-Identifier: Apache-2.0
// The engine's byte format for VkAccelerationStructureNV objects (docs/engine-nv-formats.md):
// what vkCmdBuildAccelerationStructureNV writes into the memory bound to `dst`, and what
// the engine's serialized form carries after the KHR serialization header.
//
// One layout for both levels, little-endian, position independent:
//   NvObjectHeader (96 B)
//   bottom level: NvGeometryRecord (32 B) x geometry_count
//                 NvPrimitiveRecord (48 B) x primitive_count   (active primitives, leaf order)
//   top level:    NvInstanceRecord (128 B) x instance_count   (every input record, input order)
//   NvNode (32 B) x node_count                                   (depth-first, node 0 the root)
// A bottom-level leaf covers primitive records [first, first + count); a top-level leaf
// covers instance records. An interior node's children are `first` and `first + 1`'s
// sibling: children are stored as (left = index + 1, right = first), so every child
// index is larger than its parent's and traversal of any bytes terminates.
#pragma once

#include "clastrace/vk_cluster_abi.h"

#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>

namespace clastrace::engine {

inline constexpr uint32_t kNvObjectMagic = 0x564E5443u;  // "CTNV"
inline constexpr uint8_t kNvFormatVersion = 1;
inline constexpr uint32_t kNvMaxLeafSize = 4;

enum class NvObjectKind : uint8_t { kBottomLevel = 1, kTopLevel = 2 };

struct NvObjectHeader {
    uint32_t magic;          // kNvObjectMagic
    uint8_t kind;            // NvObjectKind
    uint8_t format_version;  // kNvFormatVersion
    uint16_t reserved0;
    uint32_t build_flags;     // VkBuildAccelerationStructureFlagsNV of the build that wrote it
    uint32_t geometry_type;   // bottom level: VkGeometryTypeNV of every geometry; top level: 0
    uint64_t object_size;     // bytes used, header included
    uint32_t geometry_count;  // bottom level: geometries; top level: 0
    uint32_t
        primitive_count;  // bottom level: active primitives stored; top level: instance records
    uint32_t node_count;  // 0 when nothing is active
    uint32_t
        input_count;  // bottom level: primitives given (active or not); top level: instanceCount
    uint64_t geometries_offset;
    uint64_t primitives_offset;  // primitive or instance records
    uint64_t nodes_offset;
    uint64_t update_count;  // updates applied since the last full build
    float bounds_min[3];
    float bounds_max[3];
};
static_assert(sizeof(NvObjectHeader) == 96);

// One VkGeometryNV as built: what an update must keep (topology) and where its
// primitives went.
struct NvGeometryRecord {
    uint32_t geometry_flags;     // VkGeometryFlagsNV
    uint32_t input_primitives;   // triangles (index or vertex count / 3) or numAABBs
    uint32_t vertex_format;      // triangles: VkFormat; AABBs: 0
    uint32_t index_type;         // triangles: VkIndexType; AABBs: 0
    uint32_t vertex_count;       // triangles: vertexCount; AABBs: stride
    uint32_t has_transform;      // 1 when transformData was given
    uint32_t active_primitives;  // of input_primitives
    uint32_t reserved;
};
static_assert(sizeof(NvGeometryRecord) == 32);

// A triangle (three vertices after the geometry transform) or an AABB (min in v[0..2],
// max in v[3..5]).
struct NvPrimitiveRecord {
    float v[9];
    uint32_t geometry_index;
    uint32_t primitive_index;  // index within its geometry (gl_PrimitiveID)
    uint32_t reserved;
};
static_assert(sizeof(NvPrimitiveRecord) == 48);

// VkAccelerationStructureInstanceNV as given, plus where the engine found the BLAS.
struct NvInstanceRecord {
    float transform[12];             // 3x4 row-major object-to-world
    uint32_t custom_index_and_mask;  // instanceCustomIndex:24, mask:8
    uint32_t sbt_offset_and_flags;   // instanceShaderBindingTableRecordOffset:24, flags:8
    uint64_t reference;              // accelerationStructureReference as given (handle)
    uint64_t blas_address;           // engine address of the BLAS; 0: inactive instance
    float world_min[3];              // the instance's world box when built
    float world_max[3];
    uint32_t active;  // 1 active, 0 inactive (reference 0, NaN transform, unresolved)
    uint32_t reserved[7];
};
static_assert(sizeof(NvInstanceRecord) == 128);

struct NvNode {
    float bounds_min[3];
    uint32_t first;  // interior: right child index (left is this index + 1); leaf: first record
    float bounds_max[3];
    uint32_t count;  // 0: interior; 1..kNvMaxLeafSize: leaf
};
static_assert(sizeof(NvNode) == 32);

// The bytes an object of the given counts needs (what vkGetAccelerationStructureMemory-
// RequirementsNV answers for the engine): every primitive active, the worst-case tree.
struct NvMemoryRequirements {
    uint64_t object = 0;
    uint64_t build_scratch = 0;
    uint64_t update_scratch = 0;
};
inline constexpr uint64_t kNvObjectAlignment = 256;
NvMemoryRequirements nv_memory_requirements(bool top_level, uint64_t geometry_count,
                                            uint64_t primitive_or_instance_count);
// Bytes of a tree over `leaves_items` items: at most 2n - 1 nodes (leaves of one item).
uint64_t nv_node_bound(uint64_t items);

// A checked object: every section lies inside `bytes`, every child index is larger than
// its parent's and below node_count, every leaf range lies inside its records, every
// geometry index of a primitive is below geometry_count. Tracing a checked object is safe
// whatever its bytes hold otherwise (NaN boxes only cause misses).
struct NvObjectView {
    std::span<const std::byte> bytes;
    NvObjectHeader header{};
    NvGeometryRecord geometry(uint32_t i) const;
    NvPrimitiveRecord primitive(uint32_t i) const;
    NvInstanceRecord instance(uint32_t i) const;
    NvNode node(uint32_t i) const;
};
std::optional<NvObjectView> open_nv_object(std::span<const std::byte> bytes, std::string* error);
// Only the header (96 bytes): magic, kind, version, object_size >= 96. For sizing an
// object from its first bytes.
std::optional<NvObjectHeader> read_nv_header(std::span<const std::byte> bytes, std::string* error);

}  // namespace clastrace::engine
