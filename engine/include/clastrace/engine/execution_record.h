// SPDX-License-Identifier: Apache-2.0
// What one vkCmdBuildClusterAccelerationStructureIndirectNV did to memory: every byte
// range it read and wrote, each with the pipeline stage and access type the spec
// assigns, plus the findings and the per-op results. Replay's hazard checker consumes
// the access list; nothing here depends on how the engine built the objects.
//
// Stage/access assignment (vkCmdBuildClusterAccelerationStructureIndirectNV page):
//   scratchData                                  BUILD  AS_READ|AS_WRITE        write
//   dstImplicitData, dstAddressesArray,
//   dstSizesArray (the ranges written)           BUILD  AS_WRITE                write
//   srcInfosArray, srcInfosCount, and the
//   addresses read through an indirected field   BUILD  INDIRECT_COMMAND_READ   read
// The buffers the src infos point at are "memory with input data as identified by any used
// values of srcInfosArray" (INDIRECT_COMMAND_READ), read as the page's wording parallels
// vkCmdBuildAccelerationStructuresKHR's "input buffers as identified by any used values of
// geometry" (SHADER_READ there); and NVIDIA's own cluster samples order them (vertices a
// compute pass animated, the reference arrays a cluster build wrote) with a barrier naming
// ACCELERATION_STRUCTURE_READ at the build stage, which their driver honours. Applications take
// any of the three readings, so such a read carries all three types and replay takes a barrier
// naming any one (docs/replay.md): a hazard here is a missing or mis-staged barrier, never a
// reading of an ambiguous page:
//   index/vertex/geometry-index/OMM-index buffers,
//   clusterReferences, instantiationBoundingBoxLimit  BUILD  SHADER_READ|INDIRECT_COMMAND_READ|
//                                                             AS_READ
//   referenced CLAS, templates, move sources     BUILD  AS_READ                 read
// In explicit mode dstAddressesArray/dstSizesArray are read; the page names AS_WRITE
// for every access to them, so those reads carry AS_WRITE with is_write = false.
#pragma once

#include "clastrace/engine/field_name.h"
#include "clastrace/engine/finding.h"
#include "clastrace/vk_cluster_abi.h"

#include <cstdint>
#include <string>
#include <vector>

namespace clastrace::engine {

inline constexpr VkPipelineStageFlags2 kStageBuild =
    VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR;
inline constexpr VkAccessFlags2 kAccessIndirect = VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT;
inline constexpr VkAccessFlags2 kAccessInputBuffer = VK_ACCESS_2_SHADER_READ_BIT;
// A cluster build's read of a buffer its src infos point at: any of three types (see above).
inline constexpr VkAccessFlags2 kAccessPointedInput =
    VK_ACCESS_2_SHADER_READ_BIT | VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT |
    VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR;
inline constexpr VkAccessFlags2 kAccessObjectRead = VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR;
inline constexpr VkAccessFlags2 kAccessObjectWrite =
    VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR;
inline constexpr VkAccessFlags2 kAccessScratch = VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR |
                                                 VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR;

// One access: [begin, end) of device addresses.
struct MemoryAccess {
    uint64_t begin = 0;
    uint64_t end = 0;
    VkPipelineStageFlags2 stage = kStageBuild;
    VkAccessFlags2 access = 0;
    bool is_write = false;
    FieldName field;        // "srcInfosArray[3].vertexBuffer", "scratchData", ...
    int64_t op_index = -1;  // -1: the command as a whole (srcInfosCount, scratch, indirections)
};

// The outcome of one op (one element of srcInfosArray).
struct OpResult {
    bool executed = false;     // the op produced its output (sizes-only ops: the size)
    uint64_t dst_address = 0;  // where the object went (0 in compute-sizes mode or on failure)
    uint64_t dst_size = 0;     // bytes of the object (what dstSizesArray receives)
    VkClusterAccelerationStructureTypeNV dst_type =
        VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_MAX_ENUM_NV;
};

struct ExecutionRecord {
    VkClusterAccelerationStructureOpTypeNV op_type =
        VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MAX_ENUM_NV;
    VkClusterAccelerationStructureOpModeNV op_mode =
        VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_MAX_ENUM_NV;
    uint32_t op_count = 0;         // min(count in memory, maxAccelerationStructureCount)
    uint64_t scratch_address = 0;  // resolved (after indirection)
    uint64_t scratch_bytes_used = 0;
    uint64_t implicit_address = 0;       // dstImplicitData, resolved (after indirection)
    uint64_t implicit_bytes_used = 0;    // implicit mode: bytes packed from dstImplicitData
    std::vector<OpResult> ops;           // op_count entries, op index order
    std::vector<MemoryAccess> accesses;  // command-level first, then by op index; deterministic
    std::vector<Finding>
        findings;  // deterministic: command checks, ops by index, whole-command checks
};

}  // namespace clastrace::engine
