// SPDX-License-Identifier: Apache-2.0
// The memory layout and cluster commands the VUID and hazard catalogues are written with:
// fixed device addresses (so a test can name bytes), one buffer per role, and buffers that
// each lack one usage flag (for 12304-12308).
#pragma once

#include "trace_script.h"

#include <clastrace/vk_cluster_abi.h>

#include <cstdint>
#include <cstring>
#include <vector>

namespace clastrace::test::catalogue {

// Device addresses. Every buffer lives in memory 0x1001 at offset (address - kBase).
inline constexpr uint64_t kBase = 0x10000000;
inline constexpr uint64_t kGeometry =
    0x10000000;  // 64 KiB: vertices, indices, geometry indices, bounds
inline constexpr uint64_t kVertices = kGeometry;            // 64 float3 vertices
inline constexpr uint64_t kIndices = kGeometry + 0x8000;    // 8-bit indices
inline constexpr uint64_t kIndices16 = kGeometry + 0xA000;  // zero bytes: 16-bit indices, all 0
inline constexpr uint64_t kGeometryIndices = kGeometry + 0xC000;
inline constexpr uint64_t kMicromaps = kGeometry + 0xD000;
inline constexpr uint64_t kBounds = kGeometry + 0xE000;  // 6 floats
inline constexpr uint64_t kInfos = 0x10010000;           // 64 KiB: srcInfosArray, references, count
inline constexpr uint64_t kReferences = kInfos + 0x4000;
inline constexpr uint64_t kCount = kInfos + 0x8000;
inline constexpr uint64_t kDst = 0x10020000;  // 128 KiB each: objects
inline constexpr uint64_t kDst2 = 0x10040000;
inline constexpr uint64_t kOut = 0x10060000;  // 4 KiB: dstAddressesArray, dstSizesArray
inline constexpr uint64_t kSizes = kOut + 0x800;
inline constexpr uint64_t kScratch = 0x10070000;  // 64 KiB
inline constexpr uint64_t kScratch2 = kScratch + 0x8000;
inline constexpr uint64_t kSmallScratch = 0x10080000;  // 16 bytes: one op's scratch entry
inline constexpr uint64_t kNoStorage = 0x10090000;     // lacks STORAGE_BUFFER
inline constexpr uint64_t kNoInput =
    0x100A0000;  // lacks ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY
inline constexpr uint64_t kNoAsStorage = 0x100C0000;  // lacks ACCELERATION_STRUCTURE_STORAGE
inline constexpr uint64_t kStaging = 0x100E0000;      // TRANSFER_SRC only

// Buffer handles (vkCmdCopyBuffer/vkCmdFillBuffer name buffers, not addresses).
inline constexpr uint64_t kGeometryBuffer = 0xb001, kInfosBuffer = 0xb002, kDstBuffer = 0xb003,
                          kDst2Buffer = 0xb004, kOutBuffer = 0xb005, kScratchBuffer = 0xb006,
                          kStagingBuffer = 0xb00a;

inline constexpr uint32_t kDefaultOps = 2;
inline constexpr uint64_t kExplicitStride = 0x1000;  // explicit destinations: kDst + i * this

using TriangleInfo = VkClusterAccelerationStructureBuildTriangleClusterInfoNV;
using TemplateInfo = VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV;
using InstantiateInfo = VkClusterAccelerationStructureInstantiateClusterInfoNV;
using BottomLevelInfo = VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV;

// Writes every buffer of the layout.
void add_buffers(TraceScript& t);
// The device the catalogue runs on (clusters of at most 16 triangles/vertices, geometry
// indices below 1000).
ScriptDevice device();

// A quad (2 triangles, 4 vertices) of 8-bit indices at kIndices, vertices of cluster c at kVertices + 48c.
TriangleInfo triangle_info(uint32_t c);
TemplateInfo template_info(uint32_t c);
VkClusterAccelerationStructureTriangleClusterInputNV triangle_input();

// One vkCmdBuildClusterAccelerationStructureIndirectNV with its input snapshots.
struct ClusterCommand {
    VkClusterAccelerationStructureCommandsInfoNV info{};
    VkClusterAccelerationStructureTriangleClusterInputNV triangles{};
    VkClusterAccelerationStructureClustersBottomLevelInputNV bottom_level{};
    VkClusterAccelerationStructureMoveObjectsInputNV move{};
    std::vector<InputSnapshot> inputs;
    // Where srcInfosArray's bytes go and what they are (laid in as an input snapshot).
    uint64_t infos_address = kInfos;
    std::vector<uint8_t> infos;
    std::vector<fbs::DeviceAddressRange>
        driver_bvh;  // CmdBuildClusterAccelerationStructureIndirect.driver_bvh
    // Writes the command; returns its index within the command buffer.
    uint32_t emit(TraceScript& t);
};

enum class Destinations { kImplicit, kExplicit };

// Builders of each op type over `count` ops with the standard infos (tweak the result).
ClusterCommand triangle_clusters(Destinations mode, uint32_t count = kDefaultOps);
ClusterCommand triangle_templates(Destinations mode, uint32_t count = kDefaultOps);
// Instantiates the template at kDst (built explicitly by triangle_templates) `count` times.
ClusterCommand instantiate(uint32_t count = kDefaultOps);
ClusterCommand template_indices(uint32_t count = kDefaultOps);
// One BLAS over the explicit CLAS at kDst and kDst + kExplicitStride.
ClusterCommand bottom_level(std::vector<uint64_t> references = {kDst, kDst + kExplicitStride});
// Moves the explicit CLAS at kDst, kDst + kExplicitStride into implicit destinations at kDst2.
ClusterCommand move_clusters(uint32_t count = kDefaultOps);

// Rewrites the srcInfosArray element `op` (as struct T) through `edit`.
template <class T, class F>
void edit_info(ClusterCommand& c, uint32_t op, F edit) {
    T value;
    std::memcpy(&value, c.infos.data() + op * sizeof(T), sizeof(T));
    edit(value);
    std::memcpy(c.infos.data() + op * sizeof(T), &value, sizeof(T));
}

}  // namespace clastrace::test::catalogue
