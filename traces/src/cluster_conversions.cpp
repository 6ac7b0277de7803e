// SPDX-License-Identifier: Apache-2.0
#include <clastrace/traces/cluster_conversions.h>

#include <clastrace/common/enum_bits.h>

#include <utility>

namespace clastrace::traces {

using common::enum_bits;
using common::set_enum_bits;

fbs::StridedDeviceAddressRegion strided_region_to_record(
    const VkStridedDeviceAddressRegionKHR& region) {
    return {region.deviceAddress, region.stride, region.size};
}

VkStridedDeviceAddressRegionKHR strided_region_from_record(
    const fbs::StridedDeviceAddressRegion* record) {
    if (!record) return {0, 0, 0};
    return {record->device_address(), record->stride(), record->size()};
}

fbs::ClustersBottomLevelInputT bottom_level_input_to_record(
    const VkClusterAccelerationStructureClustersBottomLevelInputNV& input) {
    fbs::ClustersBottomLevelInputT out;
    out.max_total_cluster_count = input.maxTotalClusterCount;
    out.max_cluster_count_per_acceleration_structure =
        input.maxClusterCountPerAccelerationStructure;
    return out;
}

VkClusterAccelerationStructureClustersBottomLevelInputNV bottom_level_input_from_record(
    const fbs::ClustersBottomLevelInput& record) {
    VkClusterAccelerationStructureClustersBottomLevelInputNV out{};
    out.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_CLUSTERS_BOTTOM_LEVEL_INPUT_NV;
    out.maxTotalClusterCount = record.max_total_cluster_count();
    out.maxClusterCountPerAccelerationStructure =
        record.max_cluster_count_per_acceleration_structure();
    return out;
}

fbs::TriangleClusterInputT triangle_cluster_input_to_record(
    const VkClusterAccelerationStructureTriangleClusterInputNV& input) {
    fbs::TriangleClusterInputT out;
    out.vertex_format = enum_bits(input.vertexFormat);
    out.max_geometry_index_value = input.maxGeometryIndexValue;
    out.max_cluster_unique_geometry_count = input.maxClusterUniqueGeometryCount;
    out.max_cluster_triangle_count = input.maxClusterTriangleCount;
    out.max_cluster_vertex_count = input.maxClusterVertexCount;
    out.max_total_triangle_count = input.maxTotalTriangleCount;
    out.max_total_vertex_count = input.maxTotalVertexCount;
    out.min_position_truncate_bit_count = input.minPositionTruncateBitCount;
    return out;
}

VkClusterAccelerationStructureTriangleClusterInputNV triangle_cluster_input_from_record(
    const fbs::TriangleClusterInput& record) {
    VkClusterAccelerationStructureTriangleClusterInputNV out{};
    out.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_TRIANGLE_CLUSTER_INPUT_NV;
    set_enum_bits(out.vertexFormat, record.vertex_format());
    out.maxGeometryIndexValue = record.max_geometry_index_value();
    out.maxClusterUniqueGeometryCount = record.max_cluster_unique_geometry_count();
    out.maxClusterTriangleCount = record.max_cluster_triangle_count();
    out.maxClusterVertexCount = record.max_cluster_vertex_count();
    out.maxTotalTriangleCount = record.max_total_triangle_count();
    out.maxTotalVertexCount = record.max_total_vertex_count();
    out.minPositionTruncateBitCount = record.min_position_truncate_bit_count();
    return out;
}

fbs::MoveObjectsInputT move_objects_input_to_record(
    const VkClusterAccelerationStructureMoveObjectsInputNV& input) {
    fbs::MoveObjectsInputT out;
    out.type = enum_bits(input.type);
    out.no_move_overlap = input.noMoveOverlap == VK_TRUE;
    out.max_moved_bytes = input.maxMovedBytes;
    return out;
}

VkClusterAccelerationStructureMoveObjectsInputNV move_objects_input_from_record(
    const fbs::MoveObjectsInput& record) {
    VkClusterAccelerationStructureMoveObjectsInputNV out{};
    out.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_MOVE_OBJECTS_INPUT_NV;
    set_enum_bits(out.type, record.type());
    out.noMoveOverlap = record.no_move_overlap() ? VK_TRUE : VK_FALSE;
    out.maxMovedBytes = record.max_moved_bytes();
    return out;
}

namespace {

// The union member opType selects (VkClusterAccelerationStructureOpInputNV); NONE for an op type
// whose input has an unknown layout.
fbs::ClusterOpInput op_input_member(uint32_t op_type) {
    switch (op_type) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV:
        return fbs::ClusterOpInput::ClustersBottomLevelInput;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV:
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV:
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV:
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV:
        return fbs::ClusterOpInput::TriangleClusterInput;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV:
        return fbs::ClusterOpInput::MoveObjectsInput;
    default: return fbs::ClusterOpInput::NONE;
    }
}

void set_op_input(const VkClusterAccelerationStructureInputInfoNV& input,
                  fbs::ClusterOpInputUnion& out) {
    if (!input.opInput.pTriangleClusters) return;
    switch (op_input_member(enum_bits(input.opType))) {
    case fbs::ClusterOpInput::ClustersBottomLevelInput:
        out.Set(bottom_level_input_to_record(*input.opInput.pClustersBottomLevel));
        return;
    case fbs::ClusterOpInput::TriangleClusterInput:
        out.Set(triangle_cluster_input_to_record(*input.opInput.pTriangleClusters));
        return;
    case fbs::ClusterOpInput::MoveObjectsInput:
        out.Set(move_objects_input_to_record(*input.opInput.pMoveObjects));
        return;
    default: return;
    }
}

}  // namespace

std::unique_ptr<fbs::ClusterInputInfoT> cluster_input_to_record(
    const VkClusterAccelerationStructureInputInfoNV& input) {
    auto out = std::make_unique<fbs::ClusterInputInfoT>();
    out->max_acceleration_structure_count = input.maxAccelerationStructureCount;
    out->flags = input.flags;
    out->op_type = enum_bits(input.opType);
    out->op_mode = enum_bits(input.opMode);
    set_op_input(input, out->op_input);
    return out;
}

VkClusterAccelerationStructureInputInfoNV cluster_input_from_record(
    const fbs::ClusterInputInfo* record, ClusterOpInputStorage& storage) {
    VkClusterAccelerationStructureInputInfoNV out{};
    out.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV;
    if (!record) return out;
    out.maxAccelerationStructureCount = record->max_acceleration_structure_count();
    out.flags = record->flags();
    set_enum_bits(out.opType, record->op_type());
    set_enum_bits(out.opMode, record->op_mode());
    // Every reader takes the union's member that opType names: a record holding another one
    // (a damaged or hostile trace) would have them read past the member it holds.
    if (record->op_input_type() != op_input_member(record->op_type())) return out;
    if (const auto* t = record->op_input_as_TriangleClusterInput()) {
        storage.triangle_cluster = triangle_cluster_input_from_record(*t);
        out.opInput.pTriangleClusters = &storage.triangle_cluster;
    } else if (const auto* b = record->op_input_as_ClustersBottomLevelInput()) {
        storage.bottom_level = bottom_level_input_from_record(*b);
        out.opInput.pClustersBottomLevel = &storage.bottom_level;
    } else if (const auto* m = record->op_input_as_MoveObjectsInput()) {
        storage.move_objects = move_objects_input_from_record(*m);
        out.opInput.pMoveObjects = &storage.move_objects;
    }
    return out;
}

fbs::CmdBuildClusterAccelerationStructureIndirectT cluster_commands_to_record(
    uint64_t command_buffer, const VkClusterAccelerationStructureCommandsInfoNV& info) {
    fbs::CmdBuildClusterAccelerationStructureIndirectT out;
    out.command_buffer = command_buffer;
    out.input = cluster_input_to_record(info.input);
    out.dst_implicit_data = info.dstImplicitData;
    out.scratch_data = info.scratchData;
    out.dst_addresses_array = std::make_unique<fbs::StridedDeviceAddressRegion>(
        strided_region_to_record(info.dstAddressesArray));
    out.dst_sizes_array = std::make_unique<fbs::StridedDeviceAddressRegion>(
        strided_region_to_record(info.dstSizesArray));
    out.src_infos_array = std::make_unique<fbs::StridedDeviceAddressRegion>(
        strided_region_to_record(info.srcInfosArray));
    out.src_infos_count = info.srcInfosCount;
    out.address_resolution_flags = info.addressResolutionFlags;
    return out;
}

VkClusterAccelerationStructureCommandsInfoNV cluster_commands_from_record(
    const fbs::CmdBuildClusterAccelerationStructureIndirect& record,
    ClusterOpInputStorage& storage) {
    VkClusterAccelerationStructureCommandsInfoNV out{};
    out.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV;
    out.input = cluster_input_from_record(record.input(), storage);
    out.dstImplicitData = record.dst_implicit_data();
    out.scratchData = record.scratch_data();
    out.dstAddressesArray = strided_region_from_record(record.dst_addresses_array());
    out.dstSizesArray = strided_region_from_record(record.dst_sizes_array());
    out.srcInfosArray = strided_region_from_record(record.src_infos_array());
    out.srcInfosCount = record.src_infos_count();
    out.addressResolutionFlags = record.address_resolution_flags();
    return out;
}

}  // namespace clastrace::traces
