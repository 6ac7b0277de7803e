// SPDX-License-Identifier: Apache-2.0
// engine::execute_nv_build: one vkCmdBuildAccelerationStructureNV against a MemoryImage.
// Buffers arrive as device addresses (replay resolves VkBuffer + offset); the objects as
// NvObjectBinding (the memory bound to them and the info they were created with).
//
// Semantics the engine fixes where the spec leaves freedom (docs/engine-nv-formats.md):
// - Inactive primitives (Vulkan "Inactive Primitives and Instances"): a triangle with a
//   NaN X coordinate in any vertex, an AABB with NaN minimum X, an instance whose
//   reference is 0. NaN in another component only (undefined behaviour) makes the
//   primitive inactive too, with a finding. Indices >= vertexCount: inactive + finding.
// - The geometry transform applies to vertices in float, row-major 3x4, as the GPU does;
//   AABBs ignore it (the spec gives AABB geometry none).
// - Update (`update` = VK_TRUE): the dst keeps src's tree and primitive order, every
//   primitive is re-read and the boxes refit bottom-up. src == dst updates in place.
// - The BLAS an instance names is found through NvBuildOptions::resolve_reference (the
//   engine's own handle is the object's address, the default). Its root box, transformed
//   by the instance, is the instance's world box.
// - Scratch: the engine writes nothing there but claims the bytes its requirement names
//   (read and written, for the hazard checker).
#pragma once

#include "clastrace/engine/build_options.h"
#include "clastrace/engine/execution_record.h"
#include "clastrace/engine/memory_image.h"
#include "clastrace/engine/nv_format.h"

#include <cstdint>
#include <functional>
#include <optional>
#include <vector>

namespace clastrace::engine {

// VkGeometryTrianglesNV with each VkBuffer + offset resolved to a device address
// (0: VK_NULL_HANDLE). `*_available` is the bytes from that address to the end of the
// buffer (offset checks: 02428/02431/02437); ~0 when unknown.
struct NvTriangles {
    uint64_t vertex_address = 0;
    uint64_t vertex_available = ~0ull;
    uint64_t vertex_offset = 0;  // as given (alignment rule 02429)
    uint32_t vertex_count = 0;
    VkFormat vertex_format = VK_FORMAT_R32G32B32_SFLOAT;
    uint64_t vertex_stride = 0;
    uint64_t index_address = 0;
    uint64_t index_available = ~0ull;
    uint64_t index_offset = 0;
    uint32_t index_count = 0;
    VkIndexType index_type = VK_INDEX_TYPE_NONE_NV;
    uint64_t transform_address = 0;
    uint64_t transform_available = ~0ull;
    uint64_t transform_offset = 0;
};
struct NvAabbs {
    uint64_t address = 0;
    uint64_t available = ~0ull;
    uint64_t offset = 0;
    uint32_t count = 0;
    uint32_t stride = 0;
};
struct NvGeometry {
    VkGeometryTypeNV type = VK_GEOMETRY_TYPE_TRIANGLES_NV;
    VkGeometryFlagsNV flags = 0;
    NvTriangles triangles;
    NvAabbs aabbs;
};
// VkAccelerationStructureInfoNV.
struct NvObjectInfo {
    VkAccelerationStructureTypeNV type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_NV;
    VkBuildAccelerationStructureFlagsNV flags = 0;
    uint32_t instance_count = 0;
    std::vector<NvGeometry> geometries;
};

// A VkAccelerationStructureNV: its handle, the memory bound to it, and the info it was
// created with (nullopt when the creation was not seen).
struct NvObjectBinding {
    uint64_t handle = 0;   // VK_NULL_HANDLE: none
    bool bound = false;    // vkBindAccelerationStructureMemoryNV seen
    uint64_t address = 0;  // where its memory starts
    uint64_t size = 0;     // bytes of that memory the object may use
    std::optional<NvObjectInfo> created;
    bool built = false;  // a build or deserialize completed into it
    VkBuildAccelerationStructureFlagsNV built_flags = 0;  // flags of that build
};

struct NvBuildCommand {
    NvObjectInfo info;
    uint64_t instance_address = 0;  // instanceData + instanceOffset; 0: VK_NULL_HANDLE
    uint64_t instance_available = ~0ull;
    bool instance_buffer_ray_tracing_usage = true;  // 03523
    bool update = false;
    NvObjectBinding dst;
    NvObjectBinding src;
    uint64_t scratch_address = 0;
    uint64_t scratch_available = ~0ull;     // size of scratch minus scratchOffset
    bool scratch_ray_tracing_usage = true;  // 03522
};

// VkPhysicalDeviceRayTracingPropertiesNV limits the build checks (NVIDIA's values).
struct NvLimits {
    uint64_t max_geometry_count = kNvidiaMaxGeometryCount;
    uint64_t max_instance_count = kNvidiaMaxInstanceCount;
    uint64_t max_triangle_count = kNvidiaMaxPrimitiveCount;
};

using NvBuildOptions = BuildOptions<NvLimits>;

// Runs the command. The record's ops[0] is the object (dst_address, dst_size); its
// accesses name every range read and written (fields as in the Vulkan parameters).
ExecutionRecord execute_nv_build(const NvBuildCommand& command, MemoryImage& memory,
                                 const NvBuildOptions& options = {});

// The engine's answer to vkGetAccelerationStructureMemoryRequirementsNV for `info`.
NvMemoryRequirements nv_memory_requirements(const NvObjectInfo& info);

// Rules (VUID strings verbatim; the seed page's list is the Vulkan 1.4 one).
inline constexpr const char* kVuidNvGeometryCount =
    "VUID-vkCmdBuildAccelerationStructureNV-geometryCount-02241";
inline constexpr const char* kVuidNvDstCompatible =
    "VUID-vkCmdBuildAccelerationStructureNV-dst-02488";
inline constexpr const char* kVuidNvUpdateNoSrc =
    "VUID-vkCmdBuildAccelerationStructureNV-update-02489";
inline constexpr const char* kVuidNvUpdateNotAllowed =
    "VUID-vkCmdBuildAccelerationStructureNV-update-02490";
inline constexpr const char* kVuidNvBuildScratch =
    "VUID-vkCmdBuildAccelerationStructureNV-update-02491";
inline constexpr const char* kVuidNvUpdateScratch =
    "VUID-vkCmdBuildAccelerationStructureNV-update-02492";
inline constexpr const char* kVuidNvScratchUsage =
    "VUID-vkCmdBuildAccelerationStructureNV-scratch-03522";
inline constexpr const char* kVuidNvInstanceUsage =
    "VUID-vkCmdBuildAccelerationStructureNV-instanceData-03523";
inline constexpr const char* kVuidNvReference =
    "VUID-vkCmdBuildAccelerationStructureNV-accelerationStructureReference-12264";
inline constexpr const char* kVuidNvMadeInactive =
    "VUID-vkCmdBuildAccelerationStructureNV-update-03524";
inline constexpr const char* kVuidNvMadeActive =
    "VUID-vkCmdBuildAccelerationStructureNV-update-03525";
inline constexpr const char* kVuidNvUpdateAliasing =
    "VUID-vkCmdBuildAccelerationStructureNV-update-03526";
inline constexpr const char* kVuidNvDstBound = "VUID-vkCmdBuildAccelerationStructureNV-dst-07787";
// VkAccelerationStructureInfoNV / VkGeometryTrianglesNV / VkGeometryAABBNV (structs the page names).
inline constexpr const char* kVuidInfoInstanceCount =
    "VUID-VkAccelerationStructureInfoNV-instanceCount-02422";
inline constexpr const char* kVuidInfoTriangleCount =
    "VUID-VkAccelerationStructureInfoNV-maxTriangleCount-02423";
inline constexpr const char* kVuidInfoTopGeometries =
    "VUID-VkAccelerationStructureInfoNV-type-02425";
inline constexpr const char* kVuidInfoBottomInstances =
    "VUID-VkAccelerationStructureInfoNV-type-02426";
inline constexpr const char* kVuidInfoMixedTypes = "VUID-VkAccelerationStructureInfoNV-type-02786";
inline constexpr const char* kVuidInfoFastBoth = "VUID-VkAccelerationStructureInfoNV-flags-02592";
inline constexpr const char* kVuidVertexOffset = "VUID-VkGeometryTrianglesNV-vertexOffset-02428";
inline constexpr const char* kVuidVertexOffsetAlign =
    "VUID-VkGeometryTrianglesNV-vertexOffset-02429";
inline constexpr const char* kVuidVertexFormat = "VUID-VkGeometryTrianglesNV-vertexFormat-02430";
inline constexpr const char* kVuidIndexOffset = "VUID-VkGeometryTrianglesNV-indexOffset-02431";
inline constexpr const char* kVuidIndexOffsetAlign = "VUID-VkGeometryTrianglesNV-indexOffset-02432";
inline constexpr const char* kVuidIndexType = "VUID-VkGeometryTrianglesNV-indexType-02433";
inline constexpr const char* kVuidIndexNoneData = "VUID-VkGeometryTrianglesNV-indexData-02434";
inline constexpr const char* kVuidIndexNoneCount = "VUID-VkGeometryTrianglesNV-indexCount-02436";
inline constexpr const char* kVuidTransformOffset =
    "VUID-VkGeometryTrianglesNV-transformOffset-02437";
inline constexpr const char* kVuidTransformOffsetAlign =
    "VUID-VkGeometryTrianglesNV-transformOffset-02438";
inline constexpr const char* kVuidAabbOffset = "VUID-VkGeometryAABBNV-offset-02439";
inline constexpr const char* kVuidAabbOffsetAlign = "VUID-VkGeometryAABBNV-offset-02440";
inline constexpr const char* kVuidAabbStride = "VUID-VkGeometryAABBNV-stride-02441";
// Engine rules.
inline constexpr const char* kRuleNvUpdateTopology =
    "CLASTRACE-nv-update-topology-differs-from-src";
inline constexpr const char* kRuleNvSrcNotBuilt = "CLASTRACE-nv-update-src-holds-no-object";
inline constexpr const char* kRuleNvNanComponent = "CLASTRACE-nv-nan-outside-x-component";
inline constexpr const char* kRuleNvIndexOutOfRange = "CLASTRACE-nv-index-out-of-range";
inline constexpr const char* kRuleNvPartialTriangle = "CLASTRACE-nv-index-count-not-multiple-of-3";
inline constexpr const char* kRuleNvObjectTooLarge = "CLASTRACE-nv-object-larger-than-bound-memory";
inline constexpr const char* kRuleNvBlasNotBuilt = "CLASTRACE-nv-instance-blas-not-built";
inline constexpr const char* kRuleNvScratchOverlap = "CLASTRACE-nv-scratch-overlaps-build-data";
inline constexpr const char* kRuleNvInputOverlapsDst = "CLASTRACE-nv-input-overlaps-dst";
inline constexpr const char* kRuleNvMemoryFault = "CLASTRACE-nv-memory-fault";
inline constexpr const char* kRuleNvFindingsTruncated = "CLASTRACE-findings-truncated";

}  // namespace clastrace::engine
