// SPDX-License-Identifier: Apache-2.0
// Draws whose graphics pipeline may write through buffer device addresses (spirv_pipelines.cpp
// marks the pipeline): each draw entry point is forwarded, then recorded as a CmdDraw when the
// bound pipeline is marked, so replay sees it as a possible writer of all device-address
// memory at the stages of those shaders. Draws of other pipelines are not recorded: the hazard
// model needs nothing from them (their vertex, index and attachment accesses are not modelled).
// The KHR/AMD aliases of the indirect-count draws are not hooked (they pass through unseen).
#include "layer_state.h"

#include <cstring>

namespace clastrace::capture {
namespace {

DeviceState& device_of(VkCommandBuffer cb) { return *find_device(dispatch_key(cb)); }

VKAPI_ATTR void VKAPI_CALL CmdDraw(VkCommandBuffer cb, uint32_t vertex_count,
                                   uint32_t instance_count, uint32_t first_vertex,
                                   uint32_t first_instance) {
    device_of(cb).next.CmdDraw(cb, vertex_count, instance_count, first_vertex, first_instance);
    record_draw_through_addresses(cb, "vkCmdDraw");
}

VKAPI_ATTR void VKAPI_CALL CmdDrawIndexed(VkCommandBuffer cb, uint32_t index_count,
                                          uint32_t instance_count, uint32_t first_index,
                                          int32_t vertex_offset, uint32_t first_instance) {
    device_of(cb).next.CmdDrawIndexed(cb, index_count, instance_count, first_index, vertex_offset,
                                      first_instance);
    record_draw_through_addresses(cb, "vkCmdDrawIndexed");
}

VKAPI_ATTR void VKAPI_CALL CmdDrawIndirect(VkCommandBuffer cb, VkBuffer buffer, VkDeviceSize offset,
                                           uint32_t draw_count, uint32_t stride) {
    device_of(cb).next.CmdDrawIndirect(cb, buffer, offset, draw_count, stride);
    record_draw_through_addresses(cb, "vkCmdDrawIndirect");
}

VKAPI_ATTR void VKAPI_CALL CmdDrawIndexedIndirect(VkCommandBuffer cb, VkBuffer buffer,
                                                  VkDeviceSize offset, uint32_t draw_count,
                                                  uint32_t stride) {
    device_of(cb).next.CmdDrawIndexedIndirect(cb, buffer, offset, draw_count, stride);
    record_draw_through_addresses(cb, "vkCmdDrawIndexedIndirect");
}

VKAPI_ATTR void VKAPI_CALL CmdDrawIndirectCount(VkCommandBuffer cb, VkBuffer buffer,
                                                VkDeviceSize offset, VkBuffer count_buffer,
                                                VkDeviceSize count_offset, uint32_t max_count,
                                                uint32_t stride) {
    device_of(cb).next.CmdDrawIndirectCount(cb, buffer, offset, count_buffer, count_offset,
                                            max_count, stride);
    record_draw_through_addresses(cb, "vkCmdDrawIndirectCount");
}

VKAPI_ATTR void VKAPI_CALL CmdDrawIndexedIndirectCount(VkCommandBuffer cb, VkBuffer buffer,
                                                       VkDeviceSize offset, VkBuffer count_buffer,
                                                       VkDeviceSize count_offset,
                                                       uint32_t max_count, uint32_t stride) {
    device_of(cb).next.CmdDrawIndexedIndirectCount(cb, buffer, offset, count_buffer, count_offset,
                                                   max_count, stride);
    record_draw_through_addresses(cb, "vkCmdDrawIndexedIndirectCount");
}

VKAPI_ATTR void VKAPI_CALL CmdDrawMeshTasksEXT(VkCommandBuffer cb, uint32_t x, uint32_t y,
                                               uint32_t z) {
    device_of(cb).next.CmdDrawMeshTasksEXT(cb, x, y, z);
    record_draw_through_addresses(cb, "vkCmdDrawMeshTasksEXT");
}

VKAPI_ATTR void VKAPI_CALL CmdDrawMeshTasksIndirectEXT(VkCommandBuffer cb, VkBuffer buffer,
                                                       VkDeviceSize offset, uint32_t draw_count,
                                                       uint32_t stride) {
    device_of(cb).next.CmdDrawMeshTasksIndirectEXT(cb, buffer, offset, draw_count, stride);
    record_draw_through_addresses(cb, "vkCmdDrawMeshTasksIndirectEXT");
}

VKAPI_ATTR void VKAPI_CALL CmdDrawMeshTasksIndirectCountEXT(VkCommandBuffer cb, VkBuffer buffer,
                                                            VkDeviceSize offset,
                                                            VkBuffer count_buffer,
                                                            VkDeviceSize count_offset,
                                                            uint32_t max_count, uint32_t stride) {
    device_of(cb).next.CmdDrawMeshTasksIndirectCountEXT(cb, buffer, offset, count_buffer,
                                                        count_offset, max_count, stride);
    record_draw_through_addresses(cb, "vkCmdDrawMeshTasksIndirectCountEXT");
}

VKAPI_ATTR void VKAPI_CALL CmdDrawMeshTasksNV(VkCommandBuffer cb, uint32_t task_count,
                                              uint32_t first_task) {
    device_of(cb).next.CmdDrawMeshTasksNV(cb, task_count, first_task);
    record_draw_through_addresses(cb, "vkCmdDrawMeshTasksNV");
}

VKAPI_ATTR void VKAPI_CALL CmdDrawMeshTasksIndirectNV(VkCommandBuffer cb, VkBuffer buffer,
                                                      VkDeviceSize offset, uint32_t draw_count,
                                                      uint32_t stride) {
    device_of(cb).next.CmdDrawMeshTasksIndirectNV(cb, buffer, offset, draw_count, stride);
    record_draw_through_addresses(cb, "vkCmdDrawMeshTasksIndirectNV");
}

VKAPI_ATTR void VKAPI_CALL CmdDrawMeshTasksIndirectCountNV(VkCommandBuffer cb, VkBuffer buffer,
                                                           VkDeviceSize offset,
                                                           VkBuffer count_buffer,
                                                           VkDeviceSize count_offset,
                                                           uint32_t max_count, uint32_t stride) {
    device_of(cb).next.CmdDrawMeshTasksIndirectCountNV(cb, buffer, offset, count_buffer,
                                                       count_offset, max_count, stride);
    record_draw_through_addresses(cb, "vkCmdDrawMeshTasksIndirectCountNV");
}

}  // namespace

PFN_vkVoidFunction draw_hook(const char* name) {
#define CLASTRACE_DRAW_HOOK(fn) \
    if (std::strcmp(name, "vk" #fn) == 0) return (PFN_vkVoidFunction)fn;
    CLASTRACE_DRAW_HOOK(CmdDraw)
    CLASTRACE_DRAW_HOOK(CmdDrawIndexed)
    CLASTRACE_DRAW_HOOK(CmdDrawIndirect)
    CLASTRACE_DRAW_HOOK(CmdDrawIndexedIndirect)
    CLASTRACE_DRAW_HOOK(CmdDrawIndirectCount)
    CLASTRACE_DRAW_HOOK(CmdDrawIndexedIndirectCount)
    CLASTRACE_DRAW_HOOK(CmdDrawMeshTasksEXT)
    CLASTRACE_DRAW_HOOK(CmdDrawMeshTasksIndirectEXT)
    CLASTRACE_DRAW_HOOK(CmdDrawMeshTasksIndirectCountEXT)
    CLASTRACE_DRAW_HOOK(CmdDrawMeshTasksNV)
    CLASTRACE_DRAW_HOOK(CmdDrawMeshTasksIndirectNV)
    CLASTRACE_DRAW_HOOK(CmdDrawMeshTasksIndirectCountNV)
#undef CLASTRACE_DRAW_HOOK
    return nullptr;
}

}  // namespace clastrace::capture
