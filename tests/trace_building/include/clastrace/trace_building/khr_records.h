// SPDX-License-Identifier: Apache-2.0
// VK_KHR_acceleration_structure calls in their trace form (format 1.4), built from the engine's
// mirror of the Vulkan structs (engine/khr_build.h) field by field, as the capture layer's
// conversions record them. The caller adds the snapshots a command read.
#pragma once

#include <clastrace/engine/khr_build.h>
#include <clastrace/traces/trace_generated.h>

#include <array>
#include <cstdint>
#include <vector>

namespace clastrace::trace_building {

// vkCreateAccelerationStructureKHR on `buffer` at `offset`; `device_address` is what
// vkGetAccelerationStructureDeviceAddressKHR answered (buffer address + offset).
fbs::AccelerationStructureCreateT khr_acceleration_structure_create(
    uint64_t handle, VkAccelerationStructureTypeKHR type, uint64_t buffer, uint64_t offset,
    uint64_t size, uint64_t device_address);

// One VkAccelerationStructureBuildGeometryInfoKHR with its ranges; src and dst are named by
// their handles (KhrObject::handle).
fbs::AccelerationStructureBuildInfoKHRT khr_build_info(const engine::KhrBuildInfo& info);
// vkCmdBuildAccelerationStructuresKHR of every info of `command`.
fbs::CmdBuildAccelerationStructuresKHRT khr_build(uint64_t command_buffer,
                                                  const engine::KhrBuildCommand& command);

// vkCmdCopyAccelerationStructureKHR (api 1) or vkCmdCopyAccelerationStructureNV (api 0).
fbs::CmdCopyAccelerationStructureT acceleration_structure_copy(uint64_t command_buffer, uint8_t api,
                                                               uint64_t src, uint64_t dst,
                                                               uint32_t mode);
// vkCmdCopyAccelerationStructureToMemoryKHR (mode SERIALIZE).
fbs::CmdCopyAccelerationStructureToMemoryT acceleration_structure_serialize(uint64_t command_buffer,
                                                                            uint64_t src,
                                                                            uint64_t dst_address);
// vkCmdWriteAccelerationStructuresPropertiesKHR (api 1) / NV (api 0).
fbs::CmdWriteAccelerationStructuresPropertiesT acceleration_structure_properties(
    uint64_t command_buffer, uint8_t api, std::vector<uint64_t> structures, uint32_t query_type,
    uint64_t query_pool, uint32_t first_query);
// vkGetQueryPoolResults (64-bit values, VK_SUCCESS).
fbs::QueryPoolResultsT query_pool_results(uint64_t query_pool, uint32_t first_query,
                                          std::vector<uint64_t> values);

// A VkAccelerationStructureInstanceKHR's 64 bytes: a 3x4 row-major transform, custom index
// (24 bits), mask, SBT offset (24 bits), flags and accelerationStructureReference.
std::array<uint8_t, 64> instance_bytes(const std::array<float, 12>& transform,
                                       uint32_t custom_index, uint8_t mask, uint32_t sbt_offset,
                                       uint8_t flags, uint64_t reference);

}  // namespace clastrace::trace_building
