// SPDX-License-Identifier: Apache-2.0
// The memory read by the two other captured commands: vkCmdBuildAccelerationStructureNV
// (geometry, transforms, AABBs and instances, named by VkBuffer + offset) and
// vkCmdCopyMemoryToAccelerationStructureKHR (the serialized structure at a device address).
#pragma once

#include "clastrace/capture/capture_records.h"
#include "clastrace/capture/cluster_input_walker.h"

namespace clastrace::capture {

// Reads [offset, offset + size) of `buffer`; with `out` null only checks that it could.
using BufferMemoryReader = std::function<bool(uint64_t buffer, VkDeviceSize offset, uint64_t size,
                                              CapturedBytes* out, std::string& why)>;

ClusterMemoryWalk walk_build_acceleration_structure_nv_inputs(
    const BuildAccelerationStructureNVCommand& command, const BufferMemoryReader& read);

// The serialized header (two UUIDs, then the 64-bit total size) says how much to read.
ClusterMemoryWalk walk_copy_memory_to_acceleration_structure_inputs(
    const CopyMemoryToAccelerationStructureCommand& command, const DeviceMemoryReader& read);

}  // namespace clastrace::capture
