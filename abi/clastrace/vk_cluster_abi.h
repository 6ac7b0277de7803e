// SPDX-License-Identifier: Apache-2.0
/* VK_NV_cluster_acceleration_structure, declared for Vulkan headers that predate it.
 *
 * Debian 12 ships Vulkan headers 1.3.239; the extension arrived in 1.4.303 (spec
 * version 4). Every value below is taken from the registry's facts; when a newer
 * installed header already declares the extension, its declarations are used and
 * only the layout checks at the bottom of this file apply.
 *
 * This is the only header of ours that traces/ and engine/ depend on. */
#pragma once

#include <vulkan/vulkan_core.h>

#ifndef VK_NV_cluster_acceleration_structure
#define VK_NV_cluster_acceleration_structure 1
#define VK_NV_CLUSTER_ACCELERATION_STRUCTURE_SPEC_VERSION 4
#define VK_NV_CLUSTER_ACCELERATION_STRUCTURE_EXTENSION_NAME "VK_NV_cluster_acceleration_structure"

#define VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_FEATURES_NV ((VkStructureType)1000569000)
#define VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_PROPERTIES_NV ((VkStructureType)1000569001)
#define VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_CLUSTERS_BOTTOM_LEVEL_INPUT_NV ((VkStructureType)1000569002)
#define VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_TRIANGLE_CLUSTER_INPUT_NV ((VkStructureType)1000569003)
#define VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_MOVE_OBJECTS_INPUT_NV ((VkStructureType)1000569004)
#define VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV ((VkStructureType)1000569005)
#define VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV ((VkStructureType)1000569006)
#define VK_STRUCTURE_TYPE_RAY_TRACING_PIPELINE_CLUSTER_ACCELERATION_STRUCTURE_CREATE_INFO_NV ((VkStructureType)1000569007)

/* Values the extension adds to enums of older extensions. */
#define VK_BUILD_ACCELERATION_STRUCTURE_ALLOW_CLUSTER_OPACITY_MICROMAPS_BIT_NV ((VkBuildAccelerationStructureFlagBitsKHR)0x00001000)
#define VK_OPACITY_MICROMAP_SPECIAL_INDEX_CLUSTER_GEOMETRY_DISABLE_OPACITY_MICROMAP_NV ((VkOpacityMicromapSpecialIndexEXT)-5)

typedef enum VkClusterAccelerationStructureTypeNV {
    VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_CLUSTERS_BOTTOM_LEVEL_NV = 0,
    VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_TRIANGLE_CLUSTER_NV = 1,
    VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_TRIANGLE_CLUSTER_TEMPLATE_NV = 2,
    VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_MAX_ENUM_NV = 0x7FFFFFFF
} VkClusterAccelerationStructureTypeNV;

typedef enum VkClusterAccelerationStructureOpTypeNV {
    VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV = 0,
    VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV = 1,
    VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV = 2,
    VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV = 3,
    VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV = 4,
    VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV = 5,
    VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MAX_ENUM_NV = 0x7FFFFFFF
} VkClusterAccelerationStructureOpTypeNV;

typedef enum VkClusterAccelerationStructureOpModeNV {
    VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV = 0,
    VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV = 1,
    VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_COMPUTE_SIZES_NV = 2,
    VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_MAX_ENUM_NV = 0x7FFFFFFF
} VkClusterAccelerationStructureOpModeNV;

typedef enum VkClusterAccelerationStructureAddressResolutionFlagBitsNV {
    VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_NONE_NV = 0,
    VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_IMPLICIT_DATA_BIT_NV = 0x00000001,
    VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SCRATCH_DATA_BIT_NV = 0x00000002,
    VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_ADDRESS_ARRAY_BIT_NV = 0x00000004,
    VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_SIZES_ARRAY_BIT_NV = 0x00000008,
    VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SRC_INFOS_ARRAY_BIT_NV = 0x00000010,
    VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SRC_INFOS_COUNT_BIT_NV = 0x00000020,
    VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_FLAG_BITS_MAX_ENUM_NV = 0x7FFFFFFF
} VkClusterAccelerationStructureAddressResolutionFlagBitsNV;
typedef VkFlags VkClusterAccelerationStructureAddressResolutionFlagsNV;

typedef enum VkClusterAccelerationStructureClusterFlagBitsNV {
    VK_CLUSTER_ACCELERATION_STRUCTURE_CLUSTER_ALLOW_DISABLE_OPACITY_MICROMAPS_NV = 0x00000001,
    VK_CLUSTER_ACCELERATION_STRUCTURE_CLUSTER_FLAG_BITS_MAX_ENUM_NV = 0x7FFFFFFF
} VkClusterAccelerationStructureClusterFlagBitsNV;
typedef VkFlags VkClusterAccelerationStructureClusterFlagsNV;

typedef enum VkClusterAccelerationStructureGeometryFlagBitsNV {
    VK_CLUSTER_ACCELERATION_STRUCTURE_GEOMETRY_CULL_DISABLE_BIT_NV = 0x00000001,
    VK_CLUSTER_ACCELERATION_STRUCTURE_GEOMETRY_NO_DUPLICATE_ANYHIT_INVOCATION_BIT_NV = 0x00000002,
    VK_CLUSTER_ACCELERATION_STRUCTURE_GEOMETRY_OPAQUE_BIT_NV = 0x00000004,
    VK_CLUSTER_ACCELERATION_STRUCTURE_GEOMETRY_FLAG_BITS_MAX_ENUM_NV = 0x7FFFFFFF
} VkClusterAccelerationStructureGeometryFlagBitsNV;
typedef VkFlags VkClusterAccelerationStructureGeometryFlagsNV;

typedef enum VkClusterAccelerationStructureIndexFormatFlagBitsNV {
    VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_8BIT_NV = 0x00000001,
    VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_16BIT_NV = 0x00000002,
    VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_32BIT_NV = 0x00000004,
    VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_FLAG_BITS_MAX_ENUM_NV = 0x7FFFFFFF
} VkClusterAccelerationStructureIndexFormatFlagBitsNV;
typedef VkFlags VkClusterAccelerationStructureIndexFormatFlagsNV;

typedef struct VkPhysicalDeviceClusterAccelerationStructureFeaturesNV {
    VkStructureType sType;
    void*           pNext;
    VkBool32        clusterAccelerationStructure;
} VkPhysicalDeviceClusterAccelerationStructureFeaturesNV;

typedef struct VkPhysicalDeviceClusterAccelerationStructurePropertiesNV {
    VkStructureType sType;
    void*           pNext;
    uint32_t        maxVerticesPerCluster;
    uint32_t        maxTrianglesPerCluster;
    uint32_t        clusterScratchByteAlignment;
    uint32_t        clusterByteAlignment;
    uint32_t        clusterTemplateByteAlignment;
    uint32_t        clusterBottomLevelByteAlignment;
    uint32_t        clusterTemplateBoundsByteAlignment;
    uint32_t        maxClusterGeometryIndex;
} VkPhysicalDeviceClusterAccelerationStructurePropertiesNV;

typedef struct VkClusterAccelerationStructureClustersBottomLevelInputNV {
    VkStructureType sType;
    void*           pNext;
    uint32_t        maxTotalClusterCount;
    uint32_t        maxClusterCountPerAccelerationStructure;
} VkClusterAccelerationStructureClustersBottomLevelInputNV;

typedef struct VkClusterAccelerationStructureTriangleClusterInputNV {
    VkStructureType sType;
    void*           pNext;
    VkFormat        vertexFormat;
    uint32_t        maxGeometryIndexValue;
    uint32_t        maxClusterUniqueGeometryCount;
    uint32_t        maxClusterTriangleCount;
    uint32_t        maxClusterVertexCount;
    uint32_t        maxTotalTriangleCount;
    uint32_t        maxTotalVertexCount;
    uint32_t        minPositionTruncateBitCount;
} VkClusterAccelerationStructureTriangleClusterInputNV;

typedef struct VkClusterAccelerationStructureMoveObjectsInputNV {
    VkStructureType                      sType;
    void*                                pNext;
    VkClusterAccelerationStructureTypeNV type;
    VkBool32                             noMoveOverlap;
    VkDeviceSize                         maxMovedBytes;
} VkClusterAccelerationStructureMoveObjectsInputNV;

typedef union VkClusterAccelerationStructureOpInputNV {
    VkClusterAccelerationStructureClustersBottomLevelInputNV* pClustersBottomLevel;
    VkClusterAccelerationStructureTriangleClusterInputNV*     pTriangleClusters;
    VkClusterAccelerationStructureMoveObjectsInputNV*         pMoveObjects;
} VkClusterAccelerationStructureOpInputNV;

typedef struct VkClusterAccelerationStructureInputInfoNV {
    VkStructureType                         sType;
    void*                                   pNext;
    uint32_t                                maxAccelerationStructureCount;
    VkBuildAccelerationStructureFlagsKHR    flags;
    VkClusterAccelerationStructureOpTypeNV  opType;
    VkClusterAccelerationStructureOpModeNV  opMode;
    VkClusterAccelerationStructureOpInputNV opInput;
} VkClusterAccelerationStructureInputInfoNV;

typedef struct VkClusterAccelerationStructureCommandsInfoNV {
    VkStructureType                                        sType;
    void*                                                  pNext;
    VkClusterAccelerationStructureInputInfoNV              input;
    VkDeviceAddress                                        dstImplicitData;
    VkDeviceAddress                                        scratchData;
    VkStridedDeviceAddressRegionKHR                        dstAddressesArray;
    VkStridedDeviceAddressRegionKHR                        dstSizesArray;
    VkStridedDeviceAddressRegionKHR                        srcInfosArray;
    VkDeviceAddress                                        srcInfosCount;
    VkClusterAccelerationStructureAddressResolutionFlagsNV addressResolutionFlags;
} VkClusterAccelerationStructureCommandsInfoNV;

typedef struct VkStridedDeviceAddressNV {
    VkDeviceAddress startAddress;
    VkDeviceSize    strideInBytes;
} VkStridedDeviceAddressNV;

/* The structs below are read by the GPU from srcInfosArray: their bytes are ABI.
 * Bit-fields fill each 32-bit word from its least significant bit, as the spec
 * requires and as GCC and Clang lay them out on every target we build for. */
typedef struct VkClusterAccelerationStructureGeometryIndexAndGeometryFlagsNV {
    uint32_t geometryIndex:24;
    uint32_t reserved:5;
    uint32_t geometryFlags:3;
} VkClusterAccelerationStructureGeometryIndexAndGeometryFlagsNV;

typedef struct VkClusterAccelerationStructureMoveObjectsInfoNV {
    VkDeviceAddress srcAccelerationStructure;
} VkClusterAccelerationStructureMoveObjectsInfoNV;

typedef struct VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV {
    uint32_t        clusterReferencesCount;
    uint32_t        clusterReferencesStride;
    VkDeviceAddress clusterReferences;
} VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV;

typedef struct VkClusterAccelerationStructureBuildTriangleClusterInfoNV {
    uint32_t                                                      clusterID;
    VkClusterAccelerationStructureClusterFlagsNV                  clusterFlags;
    uint32_t                                                      triangleCount:9;
    uint32_t                                                      vertexCount:9;
    uint32_t                                                      positionTruncateBitCount:6;
    uint32_t                                                      indexType:4;
    uint32_t                                                      opacityMicromapIndexType:4;
    VkClusterAccelerationStructureGeometryIndexAndGeometryFlagsNV baseGeometryIndexAndGeometryFlags;
    uint16_t                                                      indexBufferStride;
    uint16_t                                                      vertexBufferStride;
    uint16_t                                                      geometryIndexAndFlagsBufferStride;
    uint16_t                                                      opacityMicromapIndexBufferStride;
    VkDeviceAddress                                               indexBuffer;
    VkDeviceAddress                                               vertexBuffer;
    VkDeviceAddress                                               geometryIndexAndFlagsBuffer;
    VkDeviceAddress                                               opacityMicromapArray;
    VkDeviceAddress                                               opacityMicromapIndexBuffer;
} VkClusterAccelerationStructureBuildTriangleClusterInfoNV;

typedef struct VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV {
    uint32_t                                                      clusterID;
    VkClusterAccelerationStructureClusterFlagsNV                  clusterFlags;
    uint32_t                                                      triangleCount:9;
    uint32_t                                                      vertexCount:9;
    uint32_t                                                      positionTruncateBitCount:6;
    uint32_t                                                      indexType:4;
    uint32_t                                                      opacityMicromapIndexType:4;
    VkClusterAccelerationStructureGeometryIndexAndGeometryFlagsNV baseGeometryIndexAndGeometryFlags;
    uint16_t                                                      indexBufferStride;
    uint16_t                                                      vertexBufferStride;
    uint16_t                                                      geometryIndexAndFlagsBufferStride;
    uint16_t                                                      opacityMicromapIndexBufferStride;
    VkDeviceAddress                                               indexBuffer;
    VkDeviceAddress                                               vertexBuffer;
    VkDeviceAddress                                               geometryIndexAndFlagsBuffer;
    VkDeviceAddress                                               opacityMicromapArray;
    VkDeviceAddress                                               opacityMicromapIndexBuffer;
    VkDeviceAddress                                               instantiationBoundingBoxLimit;
} VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV;

typedef struct VkClusterAccelerationStructureInstantiateClusterInfoNV {
    uint32_t                 clusterIdOffset;
    uint32_t                 geometryIndexOffset:24;
    uint32_t                 reserved:8;
    VkDeviceAddress          clusterTemplateAddress;
    VkStridedDeviceAddressNV vertexBuffer;
} VkClusterAccelerationStructureInstantiateClusterInfoNV;

typedef struct VkClusterAccelerationStructureGetTemplateIndicesInfoNV {
    VkDeviceAddress clusterTemplateAddress;
} VkClusterAccelerationStructureGetTemplateIndicesInfoNV;

typedef struct VkRayTracingPipelineClusterAccelerationStructureCreateInfoNV {
    VkStructureType sType;
    void*           pNext;
    VkBool32        allowClusterAccelerationStructure;
} VkRayTracingPipelineClusterAccelerationStructureCreateInfoNV;

typedef void(VKAPI_PTR* PFN_vkGetClusterAccelerationStructureBuildSizesNV)(
    VkDevice device, const VkClusterAccelerationStructureInputInfoNV* pInfo,
    VkAccelerationStructureBuildSizesInfoKHR* pSizeInfo);
typedef void(VKAPI_PTR* PFN_vkCmdBuildClusterAccelerationStructureIndirectNV)(
    VkCommandBuffer commandBuffer, const VkClusterAccelerationStructureCommandsInfoNV* pCommandInfos);

#endif /* VK_NV_cluster_acceleration_structure */

#if VK_NV_CLUSTER_ACCELERATION_STRUCTURE_SPEC_VERSION < 4
#error "installed vulkan_core.h declares a pre-release VK_NV_cluster_acceleration_structure (spec version < 4)"
#endif

/* Layout checks: a slip in the structs the GPU reads must not compile. */
#ifdef __cplusplus
#include <cstddef>
#define CLASTRACE_ABI_ASSERT(cond) static_assert(cond, #cond)
#else
#include <stddef.h>
#define CLASTRACE_ABI_ASSERT(cond) _Static_assert(cond, #cond)
#endif

CLASTRACE_ABI_ASSERT(sizeof(VkStridedDeviceAddressRegionKHR) == 24);
CLASTRACE_ABI_ASSERT(sizeof(VkStridedDeviceAddressNV) == 16);
CLASTRACE_ABI_ASSERT(offsetof(VkStridedDeviceAddressNV, strideInBytes) == 8);

CLASTRACE_ABI_ASSERT(sizeof(VkClusterAccelerationStructureGeometryIndexAndGeometryFlagsNV) == 4);
CLASTRACE_ABI_ASSERT(sizeof(VkClusterAccelerationStructureMoveObjectsInfoNV) == 8);
CLASTRACE_ABI_ASSERT(sizeof(VkClusterAccelerationStructureGetTemplateIndicesInfoNV) == 8);

CLASTRACE_ABI_ASSERT(sizeof(VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV) == 16);
CLASTRACE_ABI_ASSERT(offsetof(VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV, clusterReferencesStride) == 4);
CLASTRACE_ABI_ASSERT(offsetof(VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV, clusterReferences) == 8);

#define CLASTRACE_ABI_TRIANGLE_INFO_OFFSETS(T)                                  \
    CLASTRACE_ABI_ASSERT(offsetof(T, clusterID) == 0);                          \
    CLASTRACE_ABI_ASSERT(offsetof(T, clusterFlags) == 4);                       \
    CLASTRACE_ABI_ASSERT(offsetof(T, baseGeometryIndexAndGeometryFlags) == 12); \
    CLASTRACE_ABI_ASSERT(offsetof(T, indexBufferStride) == 16);                 \
    CLASTRACE_ABI_ASSERT(offsetof(T, vertexBufferStride) == 18);                \
    CLASTRACE_ABI_ASSERT(offsetof(T, geometryIndexAndFlagsBufferStride) == 20); \
    CLASTRACE_ABI_ASSERT(offsetof(T, opacityMicromapIndexBufferStride) == 22);  \
    CLASTRACE_ABI_ASSERT(offsetof(T, indexBuffer) == 24);                       \
    CLASTRACE_ABI_ASSERT(offsetof(T, vertexBuffer) == 32);                      \
    CLASTRACE_ABI_ASSERT(offsetof(T, geometryIndexAndFlagsBuffer) == 40);       \
    CLASTRACE_ABI_ASSERT(offsetof(T, opacityMicromapArray) == 48);              \
    CLASTRACE_ABI_ASSERT(offsetof(T, opacityMicromapIndexBuffer) == 56)

CLASTRACE_ABI_TRIANGLE_INFO_OFFSETS(VkClusterAccelerationStructureBuildTriangleClusterInfoNV);
CLASTRACE_ABI_ASSERT(sizeof(VkClusterAccelerationStructureBuildTriangleClusterInfoNV) == 64);
CLASTRACE_ABI_TRIANGLE_INFO_OFFSETS(VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV);
CLASTRACE_ABI_ASSERT(offsetof(VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV, instantiationBoundingBoxLimit) == 64);
CLASTRACE_ABI_ASSERT(sizeof(VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV) == 72);

CLASTRACE_ABI_ASSERT(offsetof(VkClusterAccelerationStructureInstantiateClusterInfoNV, clusterTemplateAddress) == 8);
CLASTRACE_ABI_ASSERT(offsetof(VkClusterAccelerationStructureInstantiateClusterInfoNV, vertexBuffer) == 16);
CLASTRACE_ABI_ASSERT(sizeof(VkClusterAccelerationStructureInstantiateClusterInfoNV) == 32);

/* Host-side structs: checked so a trace records them field for field. */
CLASTRACE_ABI_ASSERT(offsetof(VkClusterAccelerationStructureInputInfoNV, maxAccelerationStructureCount) == 16);
CLASTRACE_ABI_ASSERT(offsetof(VkClusterAccelerationStructureInputInfoNV, opInput) == 32);
CLASTRACE_ABI_ASSERT(sizeof(VkClusterAccelerationStructureInputInfoNV) == 40);
CLASTRACE_ABI_ASSERT(offsetof(VkClusterAccelerationStructureCommandsInfoNV, input) == 16);
CLASTRACE_ABI_ASSERT(offsetof(VkClusterAccelerationStructureCommandsInfoNV, dstImplicitData) == 56);
CLASTRACE_ABI_ASSERT(offsetof(VkClusterAccelerationStructureCommandsInfoNV, scratchData) == 64);
CLASTRACE_ABI_ASSERT(offsetof(VkClusterAccelerationStructureCommandsInfoNV, dstAddressesArray) == 72);
CLASTRACE_ABI_ASSERT(offsetof(VkClusterAccelerationStructureCommandsInfoNV, dstSizesArray) == 96);
CLASTRACE_ABI_ASSERT(offsetof(VkClusterAccelerationStructureCommandsInfoNV, srcInfosArray) == 120);
CLASTRACE_ABI_ASSERT(offsetof(VkClusterAccelerationStructureCommandsInfoNV, srcInfosCount) == 144);
CLASTRACE_ABI_ASSERT(offsetof(VkClusterAccelerationStructureCommandsInfoNV, addressResolutionFlags) == 152);
CLASTRACE_ABI_ASSERT(sizeof(VkClusterAccelerationStructureCommandsInfoNV) == 160);
CLASTRACE_ABI_ASSERT(sizeof(VkPhysicalDeviceClusterAccelerationStructurePropertiesNV) == 48);
CLASTRACE_ABI_ASSERT(sizeof(VkClusterAccelerationStructureTriangleClusterInputNV) == 48);
CLASTRACE_ABI_ASSERT(sizeof(VkClusterAccelerationStructureMoveObjectsInputNV) == 32);

#undef CLASTRACE_ABI_TRIANGLE_INFO_OFFSETS

#ifdef __cplusplus
#include <cstdint>

/* Bytes of one srcInfosArray entry per op type: the element the GPU reads at the array's
 * stride (capture's walker and the engine's resolver both step by it). */
namespace clastrace {

// 0 for an op type spec version 4 does not define.
constexpr uint32_t cluster_src_info_size(VkClusterAccelerationStructureOpTypeNV op) {
    switch (op) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV:
        return sizeof(VkClusterAccelerationStructureMoveObjectsInfoNV);
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV:
        return sizeof(VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV);
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV:
        return sizeof(VkClusterAccelerationStructureBuildTriangleClusterInfoNV);
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV:
        return sizeof(VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV);
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV:
        return sizeof(VkClusterAccelerationStructureInstantiateClusterInfoNV);
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV:
        return sizeof(VkClusterAccelerationStructureGetTemplateIndicesInfoNV);
    default: return 0;
    }
}

}  // namespace clastrace
#endif /* __cplusplus */
