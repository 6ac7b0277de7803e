// SPDX-License-Identifier: Apache-2.0
// Record bodies of the consumers of acceleration structures (format 1.4): vkCmdTraceRays*,
// dispatches and draws whose shaders use ray queries, the bindings that name the structures
// they reach, packed instances for a top level's instance buffer, and the present that ends a
// frame.
#pragma once

#include <clastrace/traces/trace_generated.h>

#include <cstdint>
#include <vector>

namespace clastrace::trace_building {

// A descriptor-set binding (source 0) of one structure: by handle, by address, or both.
fbs::AccelerationStructureBinding structure_binding(uint64_t handle, uint64_t address = 0,
                                                    uint32_t set = 0, uint32_t binding = 0,
                                                    uint32_t array_element = 0);

// vkCmdTraceRaysKHR of width x height rays, reading `structures`.
fbs::CmdTraceRaysT trace_rays(uint64_t command_buffer,
                              std::vector<fbs::AccelerationStructureBinding> structures,
                              uint32_t width = 64, uint32_t height = 64);
// vkCmdDispatch of a pipeline whose compute shader uses ray queries.
fbs::CmdDispatchT ray_query_dispatch(uint64_t command_buffer,
                                     std::vector<fbs::AccelerationStructureBinding> structures);
// vkCmdDraw of a pipeline whose shaders at `stages` (VkPipelineStageFlags2) use ray queries.
fbs::CmdDrawT ray_query_draw(uint64_t command_buffer, uint64_t stages,
                             std::vector<fbs::AccelerationStructureBinding> structures);

// VkAccelerationStructureInstanceKHR (or NV's) for each reference, identity transform, mask
// 0xFF, instanceCustomIndex = its index: 64 bytes each, the reference at byte 56.
std::vector<uint8_t> packed_instances(const std::vector<uint64_t>& references);

// vkQueuePresentKHR ending frame `frame` (0-based) on `queue`.
fbs::QueuePresentT queue_present(uint64_t queue, uint64_t frame);

}  // namespace clastrace::trace_building
