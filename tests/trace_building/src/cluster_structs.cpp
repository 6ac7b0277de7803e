// SPDX-License-Identifier: Apache-2.0
#include "clastrace/trace_building/cluster_structs.h"

#include <cstring>

namespace clastrace::trace_building {

VkClusterAccelerationStructureTriangleClusterInputNV triangle_cluster_limits(
    uint32_t max_cluster_triangles, uint32_t max_cluster_vertices, uint32_t max_total_triangles,
    uint32_t max_total_vertices) {
    VkClusterAccelerationStructureTriangleClusterInputNV t{};
    t.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_TRIANGLE_CLUSTER_INPUT_NV;
    t.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    t.maxClusterUniqueGeometryCount = 1;
    t.maxClusterTriangleCount = max_cluster_triangles;
    t.maxClusterVertexCount = max_cluster_vertices;
    t.maxTotalTriangleCount = max_total_triangles;
    t.maxTotalVertexCount = max_total_vertices;
    return t;
}

namespace {
VkClusterAccelerationStructureInputInfoNV op_input(uint32_t max_count,
                                                   VkClusterAccelerationStructureOpTypeNV type,
                                                   VkClusterAccelerationStructureOpModeNV mode) {
    VkClusterAccelerationStructureInputInfoNV in{};
    in.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV;
    in.maxAccelerationStructureCount = max_count;
    in.opType = type;
    in.opMode = mode;
    return in;
}
}  // namespace

// The op input union holds non-const pointers; nothing here or in the engine writes through them.
VkClusterAccelerationStructureInputInfoNV cluster_op_input(
    uint32_t max_count, const VkClusterAccelerationStructureTriangleClusterInputNV* triangles,
    VkClusterAccelerationStructureOpModeNV mode) {
    auto in = op_input(max_count,
                       VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV, mode);
    in.opInput.pTriangleClusters =
        const_cast<VkClusterAccelerationStructureTriangleClusterInputNV*>(triangles);
    return in;
}

VkClusterAccelerationStructureInputInfoNV cluster_op_input(
    uint32_t max_count,
    const VkClusterAccelerationStructureClustersBottomLevelInputNV* bottom_level,
    VkClusterAccelerationStructureOpModeNV mode) {
    auto in =
        op_input(max_count,
                 VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV, mode);
    in.opInput.pClustersBottomLevel =
        const_cast<VkClusterAccelerationStructureClustersBottomLevelInputNV*>(bottom_level);
    return in;
}

VkClusterAccelerationStructureInputInfoNV cluster_op_input(
    uint32_t max_count, const VkClusterAccelerationStructureMoveObjectsInputNV* moves,
    VkClusterAccelerationStructureOpModeNV mode) {
    auto in = op_input(max_count, VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV, mode);
    in.opInput.pMoveObjects = const_cast<VkClusterAccelerationStructureMoveObjectsInputNV*>(moves);
    return in;
}

VkClusterAccelerationStructureCommandsInfoNV cluster_commands(
    const VkClusterAccelerationStructureInputInfoNV& input) {
    VkClusterAccelerationStructureCommandsInfoNV info{};
    info.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV;
    info.input = input;
    return info;
}

VkClusterAccelerationStructureBuildTriangleClusterInfoNV triangle_cluster_info(
    uint32_t cluster_id, uint32_t triangles, uint32_t vertices, uint64_t index_buffer,
    uint32_t index_bytes, uint64_t vertex_buffer) {
    VkClusterAccelerationStructureBuildTriangleClusterInfoNV i;
    std::memset(&i, 0, sizeof i);  // bit-fields: no padding bit may hold garbage in a snapshot
    i.clusterID = cluster_id;
    i.triangleCount = triangles;
    i.vertexCount = vertices;
    i.indexType = index_bytes == 1   ? VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_8BIT_NV
                  : index_bytes == 2 ? VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_16BIT_NV
                                     : VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_32BIT_NV;
    i.indexBufferStride = index_bytes;
    i.vertexBufferStride = 12;
    i.indexBuffer = index_buffer;
    i.vertexBuffer = vertex_buffer;
    return i;
}

}  // namespace clastrace::trace_building
