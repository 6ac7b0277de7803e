// SPDX-License-Identifier: Apache-2.0
#include "clastrace/trace_building/cluster_records.h"

#include <clastrace/traces/cluster_conversions.h>

namespace clastrace::trace_building {

std::unique_ptr<fbs::ClusterInputInfoT> cluster_input(
    const VkClusterAccelerationStructureInputInfoNV& in) {
    return traces::cluster_input_to_record(in);
}

fbs::CmdBuildClusterAccelerationStructureIndirectT cluster_build(
    uint64_t command_buffer, const VkClusterAccelerationStructureCommandsInfoNV& info) {
    return traces::cluster_commands_to_record(command_buffer, info);
}

}  // namespace clastrace::trace_building
