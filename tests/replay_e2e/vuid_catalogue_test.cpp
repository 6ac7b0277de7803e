// SPDX-License-Identifier: Apache-2.0
// The VUID catalogue: for every valid-usage rule of vkCmdBuildClusterAccelerationStructureIndirectNV,
// VkClusterAccelerationStructureCommandsInfoNV and the per-op info structs that needs the
// memory contents or the capture's state, one trace that breaks exactly that rule and a
// twin that differs only in the broken value. The replay must report the VUID string
// verbatim at the command and op that broke it; the twin must replay clean.
// docs/replay.md maps each VUID to its case name here.
#include "catalogue_replay.h"

#include <clastrace/replay/replayer.h>
#include <clastrace/traces/trace_reader.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <set>
#include <string>
#include <unistd.h>

namespace {

using namespace clastrace;
using namespace clastrace::test;
using namespace clastrace::test::catalogue;

// One trace per rule and twin (CLASTRACE_KEEP_TRACES=1 keeps them).
std::string temp_path(const std::string& name) { return temp_trace_path("vuid_catalogue", name); }

// Where the broken rule must be reported.
struct Expected {
    uint32_t command = 0;
    int64_t op = -1;
};

using Scene = void (*)(TraceScript& t, bool broken, Expected& at);

struct VuidCase {
    const char* name;
    const char* vuid;
    Scene scene;
    // Rules the same broken value necessarily breaks too (e.g. a count above the device
    // limit is also above the input's maximum, which must not exceed that limit).
    std::vector<std::string> companions = {};
};

constexpr const char* kCountAboveInput = "CLASTRACE-count-above-triangle-cluster-input";

// Template/CLAS prerequisites: built explicitly at kDst, then a full barrier.
void prior_templates(TraceScript& t) {
    triangle_templates(Destinations::kExplicit).emit(t);
    t.full_barrier();
}
void prior_clusters(TraceScript& t) {
    triangle_clusters(Destinations::kExplicit).emit(t);
    t.full_barrier();
}

// One triangle-cluster build whose op 1 info is edited when broken.
template <class Edit>
void broken_triangle_op(TraceScript& t, bool broken, Expected& at, Edit edit) {
    ClusterCommand c = triangle_clusters(Destinations::kImplicit);
    if (broken) edit_info<TriangleInfo>(c, 1, edit);
    at = {c.emit(t), 1};
}
template <class Edit>
void broken_template_op(TraceScript& t, bool broken, Expected& at, Edit edit) {
    ClusterCommand c = triangle_templates(Destinations::kImplicit);
    if (broken) edit_info<TemplateInfo>(c, 1, edit);
    at = {c.emit(t), 1};
}
template <class Edit>
void broken_instantiate_op(TraceScript& t, bool broken, Expected& at, Edit edit) {
    prior_templates(t);
    ClusterCommand c = instantiate();
    if (broken) edit_info<InstantiateInfo>(c, 1, edit);
    at = {c.emit(t), 1};
}
template <class Edit>
void broken_input(TraceScript& t, bool broken, Expected& at, Edit edit) {
    ClusterCommand c = triangle_clusters(Destinations::kImplicit);
    if (broken) edit(c.triangles);
    at = {c.emit(t), -1};  // a rule of the command's input struct: reported once, for the command
}

// srcInfosArray.stride half the op type's info struct.
void short_stride(ClusterCommand& c, bool broken) {
    if (broken) c.info.srcInfosArray.stride /= 2;
}

const VuidCase kCases[] = {
    // ---- vkCmdBuildClusterAccelerationStructureIndirectNV ------------------------------
    {"QueriedMaxCount", "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10445",
     [](TraceScript& t, bool broken, Expected& at) {
         ClusterCommand c = triangle_clusters(Destinations::kImplicit, 3);
         VkClusterAccelerationStructureInputInfoNV queried = c.info.input;
         queried.maxAccelerationStructureCount = 2;
         queried.opInput.pTriangleClusters = &c.triangles;
         t.query_build_sizes(queried);
         c.info.input.maxAccelerationStructureCount = broken ? 3 : 2;
         c.info.srcInfosCount = kCount;
         c.inputs.push_back({kCount, bytes_of(std::vector<uint32_t>{2})});
         at = {c.emit(t), -1};
     }},
    {"ScratchSmallerThanQueried",
     "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-scratchData-12300",
     [](TraceScript& t, bool broken, Expected& at) {
         ClusterCommand c = triangle_clusters(Destinations::kImplicit);
         if (broken) c.info.scratchData = kSmallScratch;
         at = {c.emit(t), -1};
     }},
    {"ScratchMisaligned", "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-scratchData-12301",
     [](TraceScript& t, bool broken, Expected& at) {
         ClusterCommand c = triangle_clusters(Destinations::kImplicit);
         if (broken) c.info.scratchData = kScratch + 64;
         at = {c.emit(t), -1};
     }},
    {"MoveInfosStrideBelowStruct",
     "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10448",
     [](TraceScript& t, bool broken, Expected& at) {
         prior_clusters(t);
         ClusterCommand c = move_clusters();
         short_stride(c, broken);
         at = {c.emit(t), -1};
     }},
    {"BottomLevelInfosStrideBelowStruct",
     "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10449",
     [](TraceScript& t, bool broken, Expected& at) {
         prior_clusters(t);
         ClusterCommand c = bottom_level();
         short_stride(c, broken);
         at = {c.emit(t), -1};
     }},
    {"TriangleInfosStrideBelowStruct",
     "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10450",
     [](TraceScript& t, bool broken, Expected& at) {
         ClusterCommand c = triangle_clusters(Destinations::kImplicit);
         short_stride(c, broken);
         at = {c.emit(t), -1};
     }},
    {"TemplateInfosStrideBelowStruct",
     "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10451",
     [](TraceScript& t, bool broken, Expected& at) {
         ClusterCommand c = triangle_templates(Destinations::kImplicit);
         short_stride(c, broken);
         at = {c.emit(t), -1};
     }},
    {"InstantiateInfosStrideBelowStruct",
     "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10452",
     [](TraceScript& t, bool broken, Expected& at) {
         prior_templates(t);
         ClusterCommand c = instantiate();
         short_stride(c, broken);
         at = {c.emit(t), -1};
     }},
    {"TemplateIndicesInfosStrideBelowStruct",
     "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10832",
     [](TraceScript& t, bool broken, Expected& at) {
         prior_templates(t);
         ClusterCommand c = template_indices();
         short_stride(c, broken);
         at = {c.emit(t), -1};
     }},
    {"CountInMemoryAboveMax",
     "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10453",
     [](TraceScript& t, bool broken, Expected& at) {
         ClusterCommand c = triangle_clusters(Destinations::kImplicit);
         c.info.srcInfosCount = kCount;
         c.inputs.push_back({kCount, bytes_of(std::vector<uint32_t>{broken ? 5u : 2u})});
         at = {c.emit(t), -1};
     }},
    {"InfosArrayShorterThanCount",
     "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10454",
     [](TraceScript& t, bool broken, Expected& at) {
         ClusterCommand c = triangle_clusters(Destinations::kImplicit);
         if (broken)
             c.info.srcInfosArray.size = c.info.srcInfosArray.stride;  // one info for two ops
         at = {c.emit(t), -1};
     }},
    {"ExplicitDestinationsOverlap",
     "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-dstAddressesArray-12302",
     [](TraceScript& t, bool broken, Expected& at) {
         ClusterCommand c = triangle_clusters(Destinations::kExplicit);
         if (broken) c.inputs.back() = {kOut, bytes_of(std::vector<uint64_t>{kDst, kDst + 128})};
         at = {c.emit(t), -1};
     }},
    {"ExplicitDestinationOverlapsScratch",
     "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-dstAddressesArray-12302",
     [](TraceScript& t, bool broken, Expected& at) {
         ClusterCommand c = triangle_clusters(Destinations::kExplicit);
         if (broken) c.inputs.back() = {kOut, bytes_of(std::vector<uint64_t>{kDst, kScratch})};
         at = {c.emit(t), -1};
     }},
    {"ImplicitDataOverlapsScratch",
     "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-dstImplicitData-12303",
     [](TraceScript& t, bool broken, Expected& at) {
         ClusterCommand c = triangle_clusters(Destinations::kImplicit);
         if (broken) c.info.dstImplicitData = kScratch;
         at = {c.emit(t), -1};
     }},
    {"ScratchWithoutStorageUsage",
     "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-12304",
     [](TraceScript& t, bool broken, Expected& at) {
         ClusterCommand c = triangle_clusters(Destinations::kImplicit);
         if (broken) c.info.scratchData = kNoStorage;
         at = {c.emit(t), -1};
     }},
    {"InfosWithoutBuildInputUsage",
     "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-12305",
     [](TraceScript& t, bool broken, Expected& at) {
         ClusterCommand c = triangle_clusters(Destinations::kImplicit);
         if (broken) c.info.srcInfosArray.deviceAddress = c.infos_address = kNoInput;
         at = {c.emit(t), -1};
     }},
    {"CountWithoutBuildInputUsage",
     "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-12306",
     [](TraceScript& t, bool broken, Expected& at) {
         ClusterCommand c = triangle_clusters(Destinations::kImplicit);
         c.info.srcInfosCount = broken ? kNoInput + 0x8000 : kCount;
         c.inputs.push_back({c.info.srcInfosCount, bytes_of(std::vector<uint32_t>{2})});
         at = {c.emit(t), -1};
     }},
    {"AddressesWithoutStorageUsage",
     "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-12307",
     [](TraceScript& t, bool broken, Expected& at) {
         ClusterCommand c = triangle_clusters(Destinations::kImplicit);
         if (broken) c.info.dstAddressesArray.deviceAddress = kNoAsStorage;
         at = {c.emit(t), -1};
     }},
    {"ImplicitDataWithoutStorageUsage",
     "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-12308",
     [](TraceScript& t, bool broken, Expected& at) {
         ClusterCommand c = triangle_clusters(Destinations::kImplicit);
         if (broken) c.info.dstImplicitData = kNoAsStorage;
         at = {c.emit(t), -1};
     }},

    // ---- VkClusterAccelerationStructureTriangleClusterInputNV --------------------------
    {"InputVertexFormatUnsupported",
     "VUID-VkClusterAccelerationStructureTriangleClusterInputNV-vertexFormat-10439",
     [](TraceScript& t, bool broken, Expected& at) {
         broken_input(t, broken, at, [](auto& in) { in.vertexFormat = VK_FORMAT_R8_UNORM; });
     }},
    {"InputMaxTrianglesAboveDevice",
     "VUID-VkClusterAccelerationStructureTriangleClusterInputNV-maxClusterTriangleCount-10440",
     [](TraceScript& t, bool broken, Expected& at) {
         broken_input(t, broken, at, [](auto& in) { in.maxClusterTriangleCount = 17; });
     }},
    {"InputMaxVerticesAboveDevice",
     "VUID-VkClusterAccelerationStructureTriangleClusterInputNV-maxClusterVertexCount-10441",
     [](TraceScript& t, bool broken, Expected& at) {
         broken_input(t, broken, at, [](auto& in) { in.maxClusterVertexCount = 17; });
     }},
    {"InputMinTruncateAbove32",
     "VUID-VkClusterAccelerationStructureTriangleClusterInputNV-minPositionTruncateBitCount-10442",
     [](TraceScript& t, bool broken, Expected& at) {
         broken_input(t, broken, at, [](auto& in) { in.minPositionTruncateBitCount = 33; });
     },
     // Every info's positionTruncateBitCount (<= 32) is then below the minimum.
     {"VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-positionTruncateBitCount-"
      "10493"}},

    // ---- VkClusterAccelerationStructureBuildTriangleClusterInfoNV ----------------------
    {"TriangleClusterIdAllOnes",
     "VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-clusterID-10488",
     [](TraceScript& t, bool broken, Expected& at) {
         broken_triangle_op(t, broken, at, [](TriangleInfo& i) { i.clusterID = 0xFFFFFFFFu; });
     }},
    {"TriangleCountAboveDevice",
     "VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-triangleCount-10489",
     [](TraceScript& t, bool broken, Expected& at) {
         broken_triangle_op(t, broken, at, [](TriangleInfo& i) { i.triangleCount = 17; });
     },
     {kCountAboveInput}},
    {"TriangleVertexCountAboveDevice",
     "VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-vertexCount-10490",
     [](TraceScript& t, bool broken, Expected& at) {
         broken_triangle_op(t, broken, at, [](TriangleInfo& i) { i.vertexCount = 17; });
     },
     {kCountAboveInput}},
    {"TriangleIndexTypeTwoBits",
     "VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-indexType-10491",
     [](TraceScript& t, bool broken, Expected& at) {
         broken_triangle_op(t, broken, at, [](TriangleInfo& i) { i.indexType = 3; });
     }},
    {"TriangleMicromapIndexTypeTwoBits",
     "VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-opacityMicromapIndexType-10492",
     [](TraceScript& t, bool broken, Expected& at) {
         ClusterCommand c = triangle_clusters(Destinations::kImplicit);
         edit_info<TriangleInfo>(c, 1, [&](TriangleInfo& i) {
             i.opacityMicromapArray = kMicromaps;
             i.opacityMicromapIndexType = broken ? 3 : 1;
         });
         at = {c.emit(t), 1};
     }},
    {"TriangleTruncateAbove32",
     "VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-positionTruncateBitCount-10493",
     [](TraceScript& t, bool broken, Expected& at) {
         broken_triangle_op(t, broken, at,
                            [](TriangleInfo& i) { i.positionTruncateBitCount = 40; });
     }},
    {"TriangleIndexStrideNotMultiple",
     "VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-indexBufferStride-10494",
     [](TraceScript& t, bool broken, Expected& at) {
         ClusterCommand c = triangle_clusters(Destinations::kImplicit);
         edit_info<TriangleInfo>(c, 1, [&](TriangleInfo& i) {
             i.indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_16BIT_NV;
             i.indexBuffer = kIndices16;
             i.indexBufferStride = broken ? 3 : 2;
         });
         at = {c.emit(t), 1};
     }},
    {"TriangleVertexStrideNotMultiple",
     "VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-vertexBufferStride-10495",
     [](TraceScript& t, bool broken, Expected& at) {
         broken_triangle_op(t, broken, at, [](TriangleInfo& i) { i.vertexBufferStride = 14; });
     }},
    {"TriangleGeometryIndexAtDeviceLimit",
     "VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-baseGeometryIndex-10496",
     [](TraceScript& t, bool broken, Expected& at) {
         ClusterCommand c = triangle_clusters(Destinations::kImplicit);
         edit_info<TriangleInfo>(c, 1, [&](TriangleInfo& i) {
             i.baseGeometryIndexAndGeometryFlags.geometryIndex = broken ? 1000 : 999;
         });
         at = {c.emit(t), 1};
     }},
    {"TriangleGeometryReservedBits",
     "VUID-VkClusterAccelerationStructureGeometryIndexAndGeometryFlagsNV-reserved-10487",
     [](TraceScript& t, bool broken, Expected& at) {
         broken_triangle_op(t, broken, at, [](TriangleInfo& i) {
             i.baseGeometryIndexAndGeometryFlags.reserved = 1;
         });
     }},
    {"TriangleClusterFlagsUnknownBit",
     "VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-clusterFlags-parameter",
     [](TraceScript& t, bool broken, Expected& at) {
         broken_triangle_op(t, broken, at, [](TriangleInfo& i) { i.clusterFlags = 0x8; });
     }},

    // ---- VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV --------------
    {"TemplateClusterIdAllOnes",
     "VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-clusterID-10497",
     [](TraceScript& t, bool broken, Expected& at) {
         broken_template_op(t, broken, at, [](TemplateInfo& i) { i.clusterID = 0xFFFFFFFFu; });
     }},
    {"TemplateTriangleCountAboveDevice",
     "VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-triangleCount-10498",
     [](TraceScript& t, bool broken, Expected& at) {
         broken_template_op(t, broken, at, [](TemplateInfo& i) { i.triangleCount = 17; });
     },
     {kCountAboveInput}},
    {"TemplateVertexCountAboveDevice",
     "VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-vertexCount-10499",
     [](TraceScript& t, bool broken, Expected& at) {
         broken_template_op(t, broken, at, [](TemplateInfo& i) { i.vertexCount = 17; });
     },
     {kCountAboveInput}},
    {"TemplateIndexTypeTwoBits",
     "VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-indexType-10500",
     [](TraceScript& t, bool broken, Expected& at) {
         broken_template_op(t, broken, at, [](TemplateInfo& i) { i.indexType = 3; });
     }},
    {"TemplateMicromapIndexTypeTwoBits",
     "VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-"
     "opacityMicromapIndexType-10501",
     [](TraceScript& t, bool broken, Expected& at) {
         ClusterCommand c = triangle_templates(Destinations::kImplicit);
         edit_info<TemplateInfo>(c, 1, [&](TemplateInfo& i) {
             i.opacityMicromapArray = kMicromaps;
             i.opacityMicromapIndexType = broken ? 3 : 1;
         });
         at = {c.emit(t), 1};
     }},
    {"TemplateTruncateAbove32",
     "VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-"
     "positionTruncateBitCount-10502",
     [](TraceScript& t, bool broken, Expected& at) {
         broken_template_op(t, broken, at,
                            [](TemplateInfo& i) { i.positionTruncateBitCount = 40; });
     }},
    {"TemplateIndexStrideNotMultiple",
     "VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-indexBufferStride-"
     "10503",
     [](TraceScript& t, bool broken, Expected& at) {
         ClusterCommand c = triangle_templates(Destinations::kImplicit);
         edit_info<TemplateInfo>(c, 1, [&](TemplateInfo& i) {
             i.indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_16BIT_NV;
             i.indexBuffer = kIndices16;
             i.indexBufferStride = broken ? 3 : 2;
         });
         at = {c.emit(t), 1};
     }},
    {"TemplateVertexStrideNotMultiple",
     "VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-vertexBufferStride-"
     "10504",
     [](TraceScript& t, bool broken, Expected& at) {
         broken_template_op(t, broken, at, [](TemplateInfo& i) { i.vertexBufferStride = 14; });
     }},
    {"TemplateBoundsMisaligned",
     "VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-"
     "instantiationBoundingBoxLimit-10505",
     [](TraceScript& t, bool broken, Expected& at) {
         ClusterCommand c = triangle_templates(Destinations::kImplicit);
         edit_info<TemplateInfo>(c, 1, [&](TemplateInfo& i) {
             i.instantiationBoundingBoxLimit = broken ? kBounds + 8 : kBounds;
         });
         at = {c.emit(t), 1};
     }},
    {"TemplateGeometryIndexAtDeviceLimit",
     "VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-baseGeometryIndex-"
     "10506",
     [](TraceScript& t, bool broken, Expected& at) {
         ClusterCommand c = triangle_templates(Destinations::kImplicit);
         edit_info<TemplateInfo>(c, 1, [&](TemplateInfo& i) {
             i.baseGeometryIndexAndGeometryFlags.geometryIndex = broken ? 1000 : 999;
         });
         at = {c.emit(t), 1};
     }},
    {"TemplateClusterFlagsUnknownBit",
     "VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-clusterFlags-parameter",
     [](TraceScript& t, bool broken, Expected& at) {
         broken_template_op(t, broken, at, [](TemplateInfo& i) { i.clusterFlags = 0x8; });
     }},

    // ---- VkClusterAccelerationStructureInstantiateClusterInfoNV ------------------------
    {"InstantiateWithoutPositions",
     "VUID-VkClusterAccelerationStructureInstantiateClusterInfoNV-vertexBuffer-10507",
     [](TraceScript& t, bool broken, Expected& at) {
         ClusterCommand templates = triangle_templates(Destinations::kExplicit);
         edit_info<TemplateInfo>(templates, 0, [](TemplateInfo& i) { i.vertexBuffer = 0; });
         templates.emit(t);
         t.full_barrier();
         ClusterCommand c = instantiate();
         if (broken)
             edit_info<InstantiateInfo>(c, 1, [](InstantiateInfo& i) { i.vertexBuffer = {0, 0}; });
         at = {c.emit(t), 1};
     }},
    {"InstantiateVertexFormatDiffers",
     "VUID-VkClusterAccelerationStructureInstantiateClusterInfoNV-vertexBuffer-10508",
     [](TraceScript& t, bool broken, Expected& at) {
         prior_templates(t);
         ClusterCommand c = instantiate();
         if (broken) c.triangles.vertexFormat = VK_FORMAT_R32G32B32A32_SFLOAT;
         at = {c.emit(t), 0};  // every op instantiates with the command's format: op 0 first
     }},
    {"InstantiateReservedNotZero",
     "VUID-VkClusterAccelerationStructureInstantiateClusterInfoNV-reserved-10509",
     [](TraceScript& t, bool broken, Expected& at) {
         broken_instantiate_op(t, broken, at, [](InstantiateInfo& i) { i.reserved = 1; });
     }},
    {"InstantiateGeometryIndexAtDeviceLimit",
     "VUID-VkClusterAccelerationStructureInstantiateClusterInfoNV-geometryIndexOffset-10510",
     [](TraceScript& t, bool broken, Expected& at) {
         prior_templates(t);
         ClusterCommand c = instantiate();
         edit_info<InstantiateInfo>(c, 1, [&](InstantiateInfo& i) {
             i.geometryIndexOffset = broken ? 1000 : 999;
         });
         at = {c.emit(t), 1};
     }},

    // ---- VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV ------------------
    {"BottomLevelReferencesTwice",
     "VUID-VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV-clusterReferences-10484",
     [](TraceScript& t, bool broken, Expected& at) {
         prior_clusters(t);
         ClusterCommand c =
             bottom_level(broken ? std::vector<uint64_t>{kDst, kDst}
                                 : std::vector<uint64_t>{kDst, kDst + kExplicitStride});
         at = {c.emit(t), 0};
     }},
    {"BottomLevelReferencesOutsideMemory",
     "VUID-VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV-clusterReferences-10485",
     [](TraceScript& t, bool broken, Expected& at) {
         prior_clusters(t);
         ClusterCommand c = bottom_level();
         if (broken)
             edit_info<BottomLevelInfo>(c, 0, [](BottomLevelInfo& i) {
                 i.clusterReferences = 0x70000000;
             });
         at = {c.emit(t), 0};
     }},
    {"BottomLevelReferenceStrideBelow8",
     "VUID-VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV-clusterReferencesStride-"
     "10486",
     [](TraceScript& t, bool broken, Expected& at) {
         prior_clusters(t);
         ClusterCommand c = bottom_level();
         if (broken)
             edit_info<BottomLevelInfo>(c, 0,
                                        [](BottomLevelInfo& i) { i.clusterReferencesStride = 4; });
         at = {c.emit(t), 0};
     }},

    // ---- VkClusterAccelerationStructureMoveObjectsInfoNV -------------------------------
    {"MoveSourceIsNoObject",
     "VUID-VkClusterAccelerationStructureMoveObjectsInfoNV-srcAccelerationStructure-10483",
     [](TraceScript& t, bool broken, Expected& at) {
         prior_clusters(t);
         ClusterCommand c = move_clusters();
         if (broken)
             edit_info<uint64_t>(c, 1,
                                 [](uint64_t& source) { source = kDst + kExplicitStride + 0x800; });
         at = {c.emit(t), 1};
     }},
};

class VuidCatalogue : public ::testing::TestWithParam<VuidCase> {
protected:
    replay::ReplayReport run(bool broken, Expected* at) {
        return replay_catalogue_scene(temp_path(std::string(GetParam().name) +
                                                (broken ? "_broken.clt" : "_twin.clt")),
                                      [&](TraceScript& t) { GetParam().scene(t, broken, *at); });
    }
};

TEST_P(VuidCatalogue, BrokenTraceReportsItsVuidAtTheCommandAndOp) {
    const VuidCase& c = GetParam();
    Expected at;
    const replay::ReplayReport r = run(true, &at);
    const std::string text = replay::format_text(r);
    auto it = std::find_if(r.findings.begin(), r.findings.end(),
                           [&](const replay::ReplayFinding& f) { return f.rule == c.vuid; });
    ASSERT_NE(it, r.findings.end()) << "expected " << c.vuid << "\n" << text;
    EXPECT_EQ(it->where.command, at.command) << text;
    EXPECT_EQ(it->op_index, at.op) << text;
    EXPECT_EQ(it->source, replay::FindingSource::kEngine) << text;
    EXPECT_FALSE(it->message.empty());
    // Nothing else: only the rule itself and the rules the same value must break too.
    std::set<std::string> allowed(c.companions.begin(), c.companions.end());
    allowed.insert(c.vuid);
    for (const replay::ReplayFinding& f : r.findings)
        EXPECT_TRUE(allowed.count(f.rule)) << f.rule << "\n" << text;
    // Rules of the command's input struct are one finding however many ops use the input.
    if (std::string(c.vuid).starts_with(
            "VUID-VkClusterAccelerationStructureTriangleClusterInputNV-")) {
        EXPECT_EQ(std::count_if(r.findings.begin(), r.findings.end(),
                                [&](const auto& f) { return f.rule == c.vuid; }),
                  1)
            << text;
    }
    EXPECT_TRUE(r.hazards.empty()) << text;
    EXPECT_TRUE(r.trace_damage.empty()) << text;
}

TEST_P(VuidCatalogue, ValidTwinIsClean) {
    Expected at;
    const replay::ReplayReport r = run(false, &at);
    EXPECT_TRUE(r.clean()) << replay::format_text(r);
    EXPECT_GT(r.counts.cluster_ops, 0u);
}

INSTANTIATE_TEST_SUITE_P(Replay, VuidCatalogue, ::testing::ValuesIn(kCases),
                         [](const ::testing::TestParamInfo<VuidCase>& info) {
                             return std::string(info.param.name);
                         });

// Every VUID the issue lists has a case (the catalogue is the list).
TEST(VuidCatalogueCoverage, EveryListedVuidHasACase) {
    const char* listed[] = {"10445", "12300", "12301", "12302", "12303", "12304", "12305", "12306",
                            "12307", "12308", "10448", "10449", "10450", "10451", "10452", "10832",
                            "10453", "10454", "10488", "10489", "10490", "10491", "10492", "10493",
                            "10494", "10495", "10496", "10497", "10498", "10499", "10500", "10501",
                            "10502", "10503", "10504", "10505", "10506"};
    for (const char* number : listed) {
        bool found = false;
        for (const VuidCase& c : kCases)
            found |= std::string(c.vuid).ends_with(std::string("-") + number);
        EXPECT_TRUE(found) << number;
    }
}

// Two buffers over the same memory and address, only the second with the usage 12308
// requires: the address is allocated from a buffer with that usage, so nothing is reported.
// Without the second buffer the same build is 12308.
TEST(VuidCatalogueUsage, AliasedBufferWithTheUsageSatisfiesTheRule) {
    constexpr uint64_t kAliased = 0x20000000;
    for (bool with_alias : {true, false}) {
        const replay::ReplayReport r = replay_catalogue_scene(
            temp_path(with_alias ? "aliased.clt" : "unaliased.clt"), [&](TraceScript& t) {
                t.buffer(0xa001, kAliased, 0x10000,
                         VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT |
                             VK_BUFFER_USAGE_STORAGE_BUFFER_BIT,
                         0x2002, 0);
                if (with_alias)
                    t.buffer(0xa002, kAliased, 0x10000,
                             VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT |
                                 VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR,
                             0x2002, 0);
                ClusterCommand c = triangle_clusters(Destinations::kImplicit);
                c.info.dstImplicitData = kAliased;
                c.emit(t);
            });
        if (with_alias) {
            EXPECT_TRUE(r.clean()) << replay::format_text(r);
        } else {
            ASSERT_EQ(r.findings.size(), 1u) << replay::format_text(r);
            EXPECT_EQ(r.findings[0].rule,
                      "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-12308");
        }
    }
}

}  // namespace
