// SPDX-License-Identifier: Apache-2.0
// VK_NV_cluster_acceleration_structure structs <-> their trace records, written once: the
// capture layer and the test trace builders encode with the *_to_record functions, replay
// decodes with the *_from_record ones. Each pair sits together so a new field is added to both.
#pragma once

#include <clastrace/traces/trace_generated.h>
#include <clastrace/vk_cluster_abi.h>

#include <cstdint>
#include <memory>

namespace clastrace::traces {

fbs::StridedDeviceAddressRegion strided_region_to_record(
    const VkStridedDeviceAddressRegionKHR& region);
// A missing region (nullptr) reads as all zeros.
VkStridedDeviceAddressRegionKHR strided_region_from_record(
    const fbs::StridedDeviceAddressRegion* record);

fbs::ClustersBottomLevelInputT bottom_level_input_to_record(
    const VkClusterAccelerationStructureClustersBottomLevelInputNV& input);
VkClusterAccelerationStructureClustersBottomLevelInputNV bottom_level_input_from_record(
    const fbs::ClustersBottomLevelInput& record);

fbs::TriangleClusterInputT triangle_cluster_input_to_record(
    const VkClusterAccelerationStructureTriangleClusterInputNV& input);
VkClusterAccelerationStructureTriangleClusterInputNV triangle_cluster_input_from_record(
    const fbs::TriangleClusterInput& record);

// noMoveOverlap is stored as a bool: VK_TRUE is true, any other value false.
fbs::MoveObjectsInputT move_objects_input_to_record(
    const VkClusterAccelerationStructureMoveObjectsInputNV& input);
VkClusterAccelerationStructureMoveObjectsInputNV move_objects_input_from_record(
    const fbs::MoveObjectsInput& record);

// The op input structs a decoded VkClusterAccelerationStructureInputInfoNV points into: the
// caller keeps it alive as long as the decoded struct is used.
struct ClusterOpInputStorage {
    VkClusterAccelerationStructureClustersBottomLevelInputNV bottom_level{};
    VkClusterAccelerationStructureTriangleClusterInputNV triangle_cluster{};
    VkClusterAccelerationStructureMoveObjectsInputNV move_objects{};
};

// The op input is recorded only for the op types whose input struct is known (the union's
// member follows opType) and only when the pointer is not null; pNext chains are not kept.
std::unique_ptr<fbs::ClusterInputInfoT> cluster_input_to_record(
    const VkClusterAccelerationStructureInputInfoNV& input);
// opInput points into `storage` when the record holds an op input, else it is null; a missing
// record (nullptr) reads as a zeroed struct with its sType.
VkClusterAccelerationStructureInputInfoNV cluster_input_from_record(
    const fbs::ClusterInputInfo* record, ClusterOpInputStorage& storage);

// vkCmdBuildClusterAccelerationStructureIndirectNV's pCommandInfo, without snapshots (the
// caller adds what the command read and wrote).
fbs::CmdBuildClusterAccelerationStructureIndirectT cluster_commands_to_record(
    uint64_t command_buffer, const VkClusterAccelerationStructureCommandsInfoNV& info);
VkClusterAccelerationStructureCommandsInfoNV cluster_commands_from_record(
    const fbs::CmdBuildClusterAccelerationStructureIndirect& record,
    ClusterOpInputStorage& storage);

}  // namespace clastrace::traces
