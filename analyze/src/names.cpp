// SPDX-License-Identifier: Apache-2.0
#include "clastrace/analyze/report.h"
#include "clastrace/replay/replay_report.h"
#include "clastrace/vk_cluster_abi.h"

namespace clastrace::analyze {

static_assert(int(OpType::kMoveObjects) ==
              VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV);
static_assert(int(OpType::kBuildClustersBottomLevel) ==
              VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV);
static_assert(int(OpType::kBuildTriangleCluster) ==
              VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV);
static_assert(int(OpType::kBuildTriangleClusterTemplate) ==
              VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV);
static_assert(int(OpType::kInstantiateTriangleCluster) ==
              VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV);
static_assert(int(OpType::kGetClusterTemplateIndices) ==
              VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV);
static_assert(int(OpMode::kImplicitDestinations) ==
              VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV);
static_assert(int(OpMode::kExplicitDestinations) ==
              VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV);
static_assert(int(OpMode::kComputeSizes) ==
              VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_COMPUTE_SIZES_NV);

// OpType's values are the Vulkan op types (asserted above), so replay's table names them.
const char* op_type_name(OpType t) {
    return replay::cluster_op_type_name(static_cast<uint32_t>(t));
}

const char* op_type_short(OpType t) {
    switch (t) {
    case OpType::kMoveObjects: return "move";
    case OpType::kBuildClustersBottomLevel: return "blas";
    case OpType::kBuildTriangleCluster: return "clas";
    case OpType::kBuildTriangleClusterTemplate: return "template";
    case OpType::kInstantiateTriangleCluster: return "instantiate";
    case OpType::kGetClusterTemplateIndices: return "tmpl_index";
    case OpType::kOther: return "other";
    }
    return "other";
}

const char* op_mode_name(OpMode m) {
    switch (m) {
    case OpMode::kImplicitDestinations: return "implicit";
    case OpMode::kExplicitDestinations: return "explicit";
    case OpMode::kComputeSizes: return "compute_sizes";
    case OpMode::kNone: return "none";
    }
    return "none";
}

const char* region_role_name(RegionRole r) {
    switch (r) {
    case RegionRole::kBuffer: return "buffer";
    case RegionRole::kScratch: return "scratch";
    case RegionRole::kImplicitData: return "implicit_data";
    case RegionRole::kDstAddresses: return "dst_addresses";
    case RegionRole::kDstSizes: return "dst_sizes";
    case RegionRole::kSrcInfos: return "src_infos";
    case RegionRole::kSrcInfosCount: return "src_infos_count";
    case RegionRole::kObjectClas: return "object_clas";
    case RegionRole::kObjectTemplate: return "object_template";
    case RegionRole::kObjectBlas: return "object_blas";
    case RegionRole::kVertex: return "vertex";
    case RegionRole::kIndex: return "index";
    case RegionRole::kOther: return "other";
    }
    return "other";
}

const char* object_type_name(ObjectType t) {
    switch (t) {
    case ObjectType::kClas: return "clas";
    case ObjectType::kClusterTemplate: return "template";
    case ObjectType::kBlas: return "blas";
    case ObjectType::kOther: return "other";
    }
    return "other";
}

const char* overlap_kind_name(OverlapKind k) {
    return k == OverlapKind::kAliasing ? "aliasing" : "reuse";
}

}  // namespace clastrace::analyze
