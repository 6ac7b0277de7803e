#include "clastrace/analyze/report.h"
#include "clastrace/replay/replay_report.h"
#include "clastrace/vk_cluster_abi.h"

namespace clastrace::analyze {

static_assert(int(OpType::move_objects) == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV);
static_assert(int(OpType::build_clusters_bottom_level) ==
              VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV);
static_assert(int(OpType::build_triangle_cluster) ==
              VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV);
static_assert(int(OpType::build_triangle_cluster_template) ==
              VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV);
static_assert(int(OpType::instantiate_triangle_cluster) ==
              VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV);
static_assert(int(OpType::get_cluster_template_indices) ==
              VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV);
static_assert(int(OpMode::implicit_destinations) ==
              VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV);
static_assert(int(OpMode::explicit_destinations) ==
              VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV);
static_assert(int(OpMode::compute_sizes) == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_COMPUTE_SIZES_NV);

// OpType's values are the Vulkan op types (asserted above), so replay's table names them.
const char* op_type_name(OpType t) { return replay::cluster_op_type_name(static_cast<uint32_t>(t)); }

const char* op_type_short(OpType t) {
  switch (t) {
    case OpType::move_objects: return "move";
    case OpType::build_clusters_bottom_level: return "blas";
    case OpType::build_triangle_cluster: return "clas";
    case OpType::build_triangle_cluster_template: return "template";
    case OpType::instantiate_triangle_cluster: return "instantiate";
    case OpType::get_cluster_template_indices: return "tmpl_index";
    case OpType::other: return "other";
  }
  return "other";
}

const char* op_mode_name(OpMode m) {
  switch (m) {
    case OpMode::implicit_destinations: return "implicit";
    case OpMode::explicit_destinations: return "explicit";
    case OpMode::compute_sizes: return "compute_sizes";
    case OpMode::none: return "none";
  }
  return "none";
}

const char* region_role_name(RegionRole r) {
  switch (r) {
    case RegionRole::buffer: return "buffer";
    case RegionRole::scratch: return "scratch";
    case RegionRole::implicit_data: return "implicit_data";
    case RegionRole::dst_addresses: return "dst_addresses";
    case RegionRole::dst_sizes: return "dst_sizes";
    case RegionRole::src_infos: return "src_infos";
    case RegionRole::src_infos_count: return "src_infos_count";
    case RegionRole::object_clas: return "object_clas";
    case RegionRole::object_template: return "object_template";
    case RegionRole::object_blas: return "object_blas";
    case RegionRole::vertex: return "vertex";
    case RegionRole::index: return "index";
    case RegionRole::other: return "other";
  }
  return "other";
}

const char* object_type_name(ObjectType t) {
  switch (t) {
    case ObjectType::clas: return "clas";
    case ObjectType::cluster_template: return "template";
    case ObjectType::blas: return "blas";
    case ObjectType::other: return "other";
  }
  return "other";
}

const char* overlap_kind_name(OverlapKind k) { return k == OverlapKind::aliasing ? "aliasing" : "reuse"; }

}  // namespace clastrace::analyze
