// SPDX-License-Identifier: Apache-2.0
// The VK_NV_cluster_acceleration_structure structs a hand-written trace starts from, set up the
// way an application fills them (sType, R32G32B32 vertices, one geometry), and the bytes of
// what a command reads.
#pragma once

#include <clastrace/vk_cluster_abi.h>

#include <cstddef>
#include <cstdint>
#include <vector>

namespace clastrace::trace_building {

template <class T>
std::vector<uint8_t> bytes_of(const T* values, size_t count) {
    const auto* p = reinterpret_cast<const uint8_t*>(values);
    return {p, p + count * sizeof(T)};
}
template <class T>
std::vector<uint8_t> bytes_of(const std::vector<T>& values) {
    return bytes_of(values.data(), values.size());
}

// Triangle-cluster limits of R32G32B32_SFLOAT clusters of one geometry.
VkClusterAccelerationStructureTriangleClusterInputNV triangle_cluster_limits(
    uint32_t max_cluster_triangles, uint32_t max_cluster_vertices, uint32_t max_total_triangles,
    uint32_t max_total_vertices);
// VkClusterAccelerationStructureInputInfoNV of `max_count` ops; the op type follows the op input.
VkClusterAccelerationStructureInputInfoNV cluster_op_input(
    uint32_t max_count, const VkClusterAccelerationStructureTriangleClusterInputNV* triangles,
    VkClusterAccelerationStructureOpModeNV mode =
        VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV);
VkClusterAccelerationStructureInputInfoNV cluster_op_input(
    uint32_t max_count,
    const VkClusterAccelerationStructureClustersBottomLevelInputNV* bottom_level,
    VkClusterAccelerationStructureOpModeNV mode =
        VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV);
VkClusterAccelerationStructureInputInfoNV cluster_op_input(
    uint32_t max_count, const VkClusterAccelerationStructureMoveObjectsInputNV* moves,
    VkClusterAccelerationStructureOpModeNV mode =
        VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV);
// VkClusterAccelerationStructureCommandsInfoNV over `input`; the caller sets the addresses.
VkClusterAccelerationStructureCommandsInfoNV cluster_commands(
    const VkClusterAccelerationStructureInputInfoNV& input);
// One srcInfosArray entry: a cluster of `triangles` triangles whose indices (`index_bytes`
// wide: 1, 2 or 4) and 12-byte vertices start at the given device addresses.
VkClusterAccelerationStructureBuildTriangleClusterInfoNV triangle_cluster_info(
    uint32_t cluster_id, uint32_t triangles, uint32_t vertices, uint64_t index_buffer,
    uint32_t index_bytes, uint64_t vertex_buffer);

}  // namespace clastrace::trace_building
