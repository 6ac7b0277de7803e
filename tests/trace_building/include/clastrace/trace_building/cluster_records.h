// SPDX-License-Identifier: Apache-2.0
// VK_NV_cluster_acceleration_structure calls in their trace form, as a capture records them: the
// names the test traces use for traces/cluster_conversions.h, which the capture layer encodes with.
#pragma once

#include <clastrace/traces/trace_generated.h>
#include <clastrace/vk_cluster_abi.h>

#include <cstdint>
#include <memory>

namespace clastrace::trace_building {

std::unique_ptr<fbs::ClusterInputInfoT> cluster_input(
    const VkClusterAccelerationStructureInputInfoNV& input);
// vkCmdBuildClusterAccelerationStructureIndirectNV without snapshots (the caller adds them).
fbs::CmdBuildClusterAccelerationStructureIndirectT cluster_build(
    uint64_t command_buffer, const VkClusterAccelerationStructureCommandsInfoNV& info);

}  // namespace clastrace::trace_building
