// SPDX-License-Identifier: Apache-2.0
// The memory a KHR acceleration-structure command reads at execution (khr_commands.cpp records
// the commands; the pause worker calls these at the pause before each): a build's vertices,
// indices, transforms, AABBs and instances (the pointer array and each pointed instance), the
// source of an update, an indirect build's ranges; a copy's source structure.
#pragma once

#include "clastrace/capture/acceleration_structure_walker.h"
#include "clastrace/capture/capture_records.h"
#include "clastrace/capture/cluster_input_walker.h"

#include <string>
#include <vector>

namespace clastrace::capture {

// VkAccelerationStructureInstanceKHR: 64 bytes, packed.
constexpr uint64_t kKhrInstanceBytes = 64;
// VkAccelerationStructureBuildRangeInfoKHR: four uint32_t.
constexpr uint64_t kKhrBuildRangeBytes = 16;

// The `geometry_count` ranges an indirect build read from `bytes` (geometry i at i * stride;
// stride 0 means tightly packed). False + `why` when `size` bytes do not hold them.
bool khr_ranges_from_indirect_bytes(const uint8_t* bytes, uint64_t size, uint32_t geometry_count,
                                    uint32_t stride,
                                    std::vector<VkAccelerationStructureBuildRangeInfoKHR>& out,
                                    std::string& why);

// Inputs of every info of `command`. An indirect build's ranges are read first (as
// kBuildRanges ranges) and returned in `indirect_ranges`, one row per info.
ClusterMemoryWalk walk_build_acceleration_structures_khr_inputs(
    const BuildAccelerationStructuresKHRCommand& command, const DeviceMemoryReader& read,
    const BufferMemoryReader& read_buffer,
    std::vector<std::vector<VkAccelerationStructureBuildRangeInfoKHR>>& indirect_ranges);

// The source structure of a KHR copy (NV copies: nothing the layer can read).
ClusterMemoryWalk walk_copy_acceleration_structure_inputs(
    const CopyAccelerationStructureCommand& command, const BufferMemoryReader& read_buffer);

}  // namespace clastrace::capture
