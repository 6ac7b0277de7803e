// SPDX-License-Identifier: Apache-2.0
// engine::execute_khr_build: one vkCmdBuildAccelerationStructuresKHR (or the host command
// vkBuildAccelerationStructuresKHR) against a MemoryImage. Each element of pInfos, with its
// ppBuildRangeInfos row, is built by the NV machinery (nv_build.h: gathering, SAH/Morton
// tree, refit, the object format of nv_format.h), so the objects trace with NvScene and a
// KHR top level can name NV bottom levels and the other way round.
//
// What the engine fixes where the spec leaves freedom (docs/engine-khr.md):
// - Indexed triangles fetch vertex vertexData + (firstVertex + index) * vertexStride; an
//   index with firstVertex + index > maxVertex makes its triangle inactive, with a finding.
//   The vertices read are [firstVertex, maxVertex] (all of them, as a driver may).
// - Non-indexed triangles read 3 * primitiveCount vertices from vertexData + primitiveOffset
//   + firstVertex * vertexStride; maxVertex does not bound them.
// - Inactive primitives and instances, transforms, update (in place when src == dst), the
//   PREFER_FAST_BUILD/TRACE choice and the scratch claim are the NV path's (nv_build.h).
// - ALLOW_COMPACTION changes nothing: the object is already as small as the engine makes it.
// - accelerationStructureReference is a device address; KhrBuildOptions::resolve_reference
//   maps it to the engine address of a built bottom level (default: itself).
#pragma once

#include "clastrace/engine/build_options.h"
#include "clastrace/engine/execution_record.h"
#include "clastrace/engine/memory_image.h"
#include "clastrace/engine/nv_build.h"

#include <cstdint>
#include <functional>
#include <optional>
#include <span>
#include <vector>

namespace clastrace::engine {

// VkAccelerationStructureGeometryTrianglesDataKHR (device addresses).
struct KhrTriangles {
    VkFormat vertex_format = VK_FORMAT_R32G32B32_SFLOAT;
    uint64_t vertex_data = 0;
    uint64_t vertex_stride = 12;
    uint32_t max_vertex = 0;
    VkIndexType index_type = VK_INDEX_TYPE_NONE_KHR;
    uint64_t index_data = 0;
    uint64_t transform_data = 0;  // 0: no transform
};
// VkAccelerationStructureGeometryAabbsDataKHR.
struct KhrAabbs {
    uint64_t data = 0;
    uint64_t stride = 24;
};
// VkAccelerationStructureGeometryInstancesDataKHR.
struct KhrInstances {
    bool array_of_pointers = false;
    uint64_t data = 0;
};
// VkAccelerationStructureGeometryKHR.
struct KhrGeometry {
    VkGeometryTypeKHR type = VK_GEOMETRY_TYPE_TRIANGLES_KHR;
    VkGeometryFlagsKHR flags = 0;
    KhrTriangles triangles;
    KhrAabbs aabbs;
    KhrInstances instances;
};
// VkAccelerationStructureBuildRangeInfoKHR.
struct KhrBuildRange {
    uint32_t primitive_count = 0;
    uint32_t primitive_offset = 0;
    uint32_t first_vertex = 0;
    uint32_t transform_offset = 0;
};
// A VkAccelerationStructureKHR: where vkCreateAccelerationStructureKHR put it (buffer
// address + offset) and the size and type it was created with.
struct KhrObject {
    uint64_t handle = 0;   // VK_NULL_HANDLE: none
    bool bound = true;     // the buffer it was created on is bound to memory (03707/03708)
    uint64_t address = 0;  // vkGetAccelerationStructureDeviceAddressKHR
    uint64_t size = 0;     // VkAccelerationStructureCreateInfoKHR::size
    VkAccelerationStructureTypeKHR type = VK_ACCELERATION_STRUCTURE_TYPE_GENERIC_KHR;
};
// VkAccelerationStructureBuildGeometryInfoKHR with its ppBuildRangeInfos row.
struct KhrBuildInfo {
    VkAccelerationStructureTypeKHR type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR;
    VkBuildAccelerationStructureFlagsKHR flags = 0;
    VkBuildAccelerationStructureModeKHR mode = VK_BUILD_ACCELERATION_STRUCTURE_MODE_BUILD_KHR;
    KhrObject src;
    KhrObject dst;
    std::vector<KhrGeometry> geometries;
    uint64_t scratch_address = 0;        // scratchData.deviceAddress
    uint64_t scratch_available = ~0ull;  // bytes from there to the end of its buffer
    std::vector<KhrBuildRange> ranges;   // one per geometry
    // The scratch size the application was told (a driver's trace: that driver's
    // vkGetAccelerationStructureBuildSizesKHR answer), which the checks between infos hold
    // against it instead of the engine's own need. ~0: none known.
    uint64_t scratch_claim = ~0ull;
};
struct KhrBuildCommand {
    std::vector<KhrBuildInfo> infos;
};

// VkPhysicalDeviceAccelerationStructurePropertiesKHR (the values NVIDIA reports).
struct KhrLimits {
    uint64_t max_geometry_count = kNvidiaMaxGeometryCount;
    uint64_t max_instance_count = kNvidiaMaxInstanceCount;
    uint64_t max_primitive_count = kNvidiaMaxPrimitiveCount;
    uint32_t min_scratch_offset_alignment = 128;
};

using KhrBuildOptions = BuildOptions<KhrLimits>;

// Runs every info in pInfos order (the spec orders none; valid usage keeps them apart).
// The record has one op per info (dst_address, dst_size); its accesses and findings carry
// the info's index, fields named as in the Vulkan structs
// ("pInfos[0].pGeometries[1].geometry.triangles.vertexData").
// record.scratch_address / scratch_bytes_used describe pInfos[0]'s scratch only; every
// info's scratch is among the accesses ("pInfos[i].scratchData").
ExecutionRecord execute_khr_build(const KhrBuildCommand& command, MemoryImage& memory,
                                  const KhrBuildOptions& options = {});

// VkAccelerationStructureBuildSizesInfoKHR.
struct KhrBuildSizes {
    uint64_t acceleration_structure_size = 0;
    uint64_t update_scratch_size = 0;
    uint64_t build_scratch_size = 0;
};
// The engine's answer to vkGetAccelerationStructureBuildSizesKHR: `max_primitive_counts`
// holds pMaxPrimitiveCounts (one per geometry; instances for a top level).
KhrBuildSizes khr_build_sizes(VkAccelerationStructureTypeKHR type,
                              std::span<const KhrGeometry> geometries,
                              std::span<const uint32_t> max_primitive_counts);

// Rules (VUID strings verbatim from the vkCmdBuildAccelerationStructuresKHR page).
inline constexpr const char* kVuidKhrMode = "VUID-vkCmdBuildAccelerationStructuresKHR-mode-04628";
inline constexpr const char* kVuidKhrUpdateNoSrc =
    "VUID-vkCmdBuildAccelerationStructuresKHR-pInfos-04630";
inline constexpr const char* kVuidKhrSrcIsOtherDst =
    "VUID-vkCmdBuildAccelerationStructuresKHR-pInfos-03403";
inline constexpr const char* kVuidKhrSameDst =
    "VUID-vkCmdBuildAccelerationStructuresKHR-dstAccelerationStructure-03698";
inline constexpr const char* kVuidKhrTopDstType =
    "VUID-vkCmdBuildAccelerationStructuresKHR-pInfos-03699";
inline constexpr const char* kVuidKhrBottomDstType =
    "VUID-vkCmdBuildAccelerationStructuresKHR-pInfos-03700";
inline constexpr const char* kVuidKhrMadeActive =
    "VUID-vkCmdBuildAccelerationStructuresKHR-pInfos-03663";
inline constexpr const char* kVuidKhrMadeInactive =
    "VUID-vkCmdBuildAccelerationStructuresKHR-pInfos-03664";
inline constexpr const char* kVuidKhrDstInOtherInstances =
    "VUID-vkCmdBuildAccelerationStructuresKHR-None-03407";
inline constexpr const char* kVuidKhrDstOverlapsOtherSrc =
    "VUID-vkCmdBuildAccelerationStructuresKHR-dstAccelerationStructure-03701";
inline constexpr const char* kVuidKhrDstOverlapsDst =
    "VUID-vkCmdBuildAccelerationStructuresKHR-dstAccelerationStructure-03702";
inline constexpr const char* kVuidKhrDstOverlapsScratch =
    "VUID-vkCmdBuildAccelerationStructuresKHR-dstAccelerationStructure-03703";
inline constexpr const char* kVuidKhrScratchOverlapsScratch =
    "VUID-vkCmdBuildAccelerationStructuresKHR-scratchData-03704";
inline constexpr const char* kVuidKhrScratchOverlapsSrc =
    "VUID-vkCmdBuildAccelerationStructuresKHR-scratchData-03705";
inline constexpr const char* kVuidKhrDstOverlapsOtherBlas =
    "VUID-vkCmdBuildAccelerationStructuresKHR-dstAccelerationStructure-03706";
inline constexpr const char* kVuidKhrUpdateNotAllowed =
    "VUID-vkCmdBuildAccelerationStructuresKHR-pInfos-03667";
inline constexpr const char* kVuidKhrUpdateAliasing =
    "VUID-vkCmdBuildAccelerationStructuresKHR-pInfos-03668";
inline constexpr const char* kVuidKhrUpdateGeometryCount =
    "VUID-vkCmdBuildAccelerationStructuresKHR-pInfos-03758";
inline constexpr const char* kVuidKhrUpdateFlags =
    "VUID-vkCmdBuildAccelerationStructuresKHR-pInfos-03759";
inline constexpr const char* kVuidKhrUpdateType =
    "VUID-vkCmdBuildAccelerationStructuresKHR-pInfos-03760";
inline constexpr const char* kVuidKhrInstanceCount =
    "VUID-vkCmdBuildAccelerationStructuresKHR-pInfos-03801";
inline constexpr const char* kVuidKhrDstBound =
    "VUID-vkCmdBuildAccelerationStructuresKHR-pInfos-03707";
inline constexpr const char* kVuidKhrSrcBound =
    "VUID-vkCmdBuildAccelerationStructuresKHR-pInfos-03708";
inline constexpr const char* kVuidKhrBuildScratch =
    "VUID-vkCmdBuildAccelerationStructuresKHR-pInfos-03671";
inline constexpr const char* kVuidKhrUpdateScratch =
    "VUID-vkCmdBuildAccelerationStructuresKHR-pInfos-03672";
inline constexpr const char* kVuidKhrScratchAlignment =
    "VUID-vkCmdBuildAccelerationStructuresKHR-pInfos-03710";
inline constexpr const char* kVuidKhrVertexAlignment =
    "VUID-vkCmdBuildAccelerationStructuresKHR-pInfos-03711";
inline constexpr const char* kVuidKhrIndexAlignment =
    "VUID-vkCmdBuildAccelerationStructuresKHR-pInfos-03712";
inline constexpr const char* kVuidKhrTransformAlignment =
    "VUID-vkCmdBuildAccelerationStructuresKHR-pInfos-03810";
inline constexpr const char* kVuidKhrAabbAlignment =
    "VUID-vkCmdBuildAccelerationStructuresKHR-pInfos-03714";
inline constexpr const char* kVuidKhrInstancesAlignment =
    "VUID-vkCmdBuildAccelerationStructuresKHR-pInfos-03715";
inline constexpr const char* kVuidKhrPointersAlignment =
    "VUID-vkCmdBuildAccelerationStructuresKHR-pInfos-03716";
inline constexpr const char* kVuidKhrPointerAlignment =
    "VUID-vkCmdBuildAccelerationStructuresKHR-pInfos-03717";
inline constexpr const char* kVuidKhrReference =
    "VUID-vkCmdBuildAccelerationStructuresKHR-pInfos-06707";
inline constexpr const char* kVuidKhrDstSize =
    "VUID-vkCmdBuildAccelerationStructuresKHR-pInfos-10126";
// Engine rules.
inline constexpr const char* kRuleKhrBadInfo = "CLASTRACE-khr-build-info-unusable";
inline constexpr const char* kRuleKhrUpdateTopology =
    "CLASTRACE-khr-update-topology-differs-from-src";
inline constexpr const char* kRuleKhrSrcNotBuilt = "CLASTRACE-khr-update-src-holds-no-object";
inline constexpr const char* kRuleKhrNanComponent = "CLASTRACE-khr-nan-outside-x-component";
inline constexpr const char* kRuleKhrIndexAboveMaxVertex = "CLASTRACE-khr-index-above-max-vertex";
inline constexpr const char* kRuleKhrBlasNotBuilt = "CLASTRACE-khr-instance-blas-not-built";
inline constexpr const char* kRuleKhrScratchOverlap = "CLASTRACE-khr-scratch-overlaps-build-data";
inline constexpr const char* kRuleKhrInputOverlapsDst = "CLASTRACE-khr-input-overlaps-dst";
inline constexpr const char* kRuleKhrMemoryFault = "CLASTRACE-khr-memory-fault";
inline constexpr const char* kRuleKhrObjectTooLarge = "CLASTRACE-khr-object-larger-than-dst";

}  // namespace clastrace::engine
