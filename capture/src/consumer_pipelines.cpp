// SPDX-License-Identifier: Apache-2.0
// Ray-tracing pipelines (vkCreateRayTracingPipelinesKHR/NV) are marked like compute and graphics
// pipelines (spirv_pipelines.cpp): the ray-tracing stage when a shader may write through buffer
// device addresses (their rays are then possible writers, as dispatches are) or uses ray
// queries. Stages taken from pipeline libraries and pipelines whose creation is deferred
// (a VkDeferredOperationKHR) are not followed: their handles are not known on return.
#include "layer_state.h"

#include <cstring>

namespace clastrace::capture {
namespace {

DeviceState& device_of(VkDevice device) { return *find_device(dispatch_key(device)); }

template <typename Info>
void mark_ray_tracing_pipelines(DeviceState& d, uint32_t count, const Info* infos,
                                const VkPipeline* pipelines) {
    std::lock_guard lock(d.pipelines_mutex);
    for (uint32_t i = 0; i < count; ++i)
        if (pipelines[i] != VK_NULL_HANDLE)
            mark_pipeline_stages(d, handle_id(pipelines[i]), infos[i].pStages, infos[i].stageCount);
}

VKAPI_ATTR VkResult VKAPI_CALL CreateRayTracingPipelinesKHR(
    VkDevice device, VkDeferredOperationKHR deferred, VkPipelineCache cache, uint32_t count,
    const VkRayTracingPipelineCreateInfoKHR* infos, const VkAllocationCallbacks* allocator,
    VkPipeline* pipelines) {
    DeviceState& d = device_of(device);
    const VkResult result = d.next.CreateRayTracingPipelinesKHR(device, deferred, cache, count,
                                                                infos, allocator, pipelines);
    if (result == VK_OPERATION_DEFERRED_KHR) {
        log_message(LogLevel::kInfo,
                    "vkCreateRayTracingPipelinesKHR: deferred creation; its pipelines are not "
                    "marked for ray queries or address writes");
        return result;
    }
    mark_ray_tracing_pipelines(d, count, infos, pipelines);
    return result;
}

VKAPI_ATTR VkResult VKAPI_CALL
CreateRayTracingPipelinesNV(VkDevice device, VkPipelineCache cache, uint32_t count,
                            const VkRayTracingPipelineCreateInfoNV* infos,
                            const VkAllocationCallbacks* allocator, VkPipeline* pipelines) {
    DeviceState& d = device_of(device);
    const VkResult result =
        d.next.CreateRayTracingPipelinesNV(device, cache, count, infos, allocator, pipelines);
    mark_ray_tracing_pipelines(d, count, infos, pipelines);
    return result;
}

}  // namespace

PFN_vkVoidFunction consumer_pipeline_hook(const char* name) {
    if (std::strcmp(name, "vkCreateRayTracingPipelinesKHR") == 0)
        return (PFN_vkVoidFunction)CreateRayTracingPipelinesKHR;
    if (std::strcmp(name, "vkCreateRayTracingPipelinesNV") == 0)
        return (PFN_vkVoidFunction)CreateRayTracingPipelinesNV;
    return nullptr;
}

}  // namespace clastrace::capture
