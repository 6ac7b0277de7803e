// VK_NV_cluster_acceleration_structure calls in their trace form, as a capture records them.
#pragma once

#include <clastrace/traces/trace_generated.h>
#include <clastrace/vk_cluster_abi.h>

#include <cstdint>
#include <memory>

namespace clastrace::trace_building {

std::unique_ptr<fbs::ClusterInputInfoT> cluster_input(const VkClusterAccelerationStructureInputInfoNV& input);
std::unique_ptr<fbs::StridedDeviceAddressRegion> strided_region(const VkStridedDeviceAddressRegionKHR& region);
// vkCmdBuildClusterAccelerationStructureIndirectNV without snapshots (the caller adds them).
fbs::CmdBuildClusterAccelerationStructureIndirectT cluster_build(uint64_t command_buffer,
                                                                 const VkClusterAccelerationStructureCommandsInfoNV& info);

}  // namespace clastrace::trace_building
