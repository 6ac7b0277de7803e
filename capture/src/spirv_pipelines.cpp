// SPDX-License-Identifier: Apache-2.0
// Which pipelines may write through buffer device addresses: vkCreateShaderModule scans the
// SPIR-V (spirv_scan.h), vkCreateComputePipelines and vkCreateGraphicsPipelines mark a pipeline
// with the pipeline stages whose shader uses a marked module (or a VkShaderModuleCreateInfo
// chained to the stage, as maintenance5 allows), and the dispatch and draw hooks
// (layer_commands.cpp, spirv_draws.cpp) ask `address_writing_stages`. With
// CLASTRACE_DEVICE_ADDRESS_WRITES=off nothing is marked for addresses. Ray queries are marked
// the same way whenever the capture is on (`ray_query_stages`), so ray-query dispatches and
// draws are recorded with the acceleration structures they reach (consumer_commands.cpp), and
// so are shaders that turn a value from memory into a structure (their bound buffers are then
// searched for structure addresses: consumer_buffer_addresses.cpp).
#include "layer_state.h"

#include "clastrace/capture/spirv_scan.h"

#include <cstring>

namespace clastrace::capture {
namespace {

DeviceState& device_of(VkDevice device) { return *find_device(dispatch_key(device)); }

bool marking_on() { return layer_config().mark_device_address_writers; }

// Ray queries matter only to a capture: without a sink nothing records the consumers.
bool scanning_on(DeviceState& d) { return marking_on() || d.sink; }

// The pipeline stage a shader stage runs in (the stages a draw's shaders can run in).
VkPipelineStageFlags2 pipeline_stage_of(VkShaderStageFlagBits stage) {
    switch (stage) {
    case VK_SHADER_STAGE_VERTEX_BIT: return VK_PIPELINE_STAGE_2_VERTEX_SHADER_BIT;
    case VK_SHADER_STAGE_TESSELLATION_CONTROL_BIT:
        return VK_PIPELINE_STAGE_2_TESSELLATION_CONTROL_SHADER_BIT;
    case VK_SHADER_STAGE_TESSELLATION_EVALUATION_BIT:
        return VK_PIPELINE_STAGE_2_TESSELLATION_EVALUATION_SHADER_BIT;
    case VK_SHADER_STAGE_GEOMETRY_BIT: return VK_PIPELINE_STAGE_2_GEOMETRY_SHADER_BIT;
    case VK_SHADER_STAGE_FRAGMENT_BIT: return VK_PIPELINE_STAGE_2_FRAGMENT_SHADER_BIT;
    case VK_SHADER_STAGE_COMPUTE_BIT: return VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT;
    case VK_SHADER_STAGE_TASK_BIT_EXT: return VK_PIPELINE_STAGE_2_TASK_SHADER_BIT_EXT;
    case VK_SHADER_STAGE_MESH_BIT_EXT: return VK_PIPELINE_STAGE_2_MESH_SHADER_BIT_EXT;
    case VK_SHADER_STAGE_RAYGEN_BIT_KHR:
    case VK_SHADER_STAGE_ANY_HIT_BIT_KHR:
    case VK_SHADER_STAGE_CLOSEST_HIT_BIT_KHR:
    case VK_SHADER_STAGE_MISS_BIT_KHR:
    case VK_SHADER_STAGE_INTERSECTION_BIT_KHR:
    case VK_SHADER_STAGE_CALLABLE_BIT_KHR: return VK_PIPELINE_STAGE_2_RAY_TRACING_SHADER_BIT_KHR;
    default: return VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT;  // a stage this list does not know
    }
}


VKAPI_ATTR VkResult VKAPI_CALL CreateShaderModule(VkDevice device,
                                                  const VkShaderModuleCreateInfo* info,
                                                  const VkAllocationCallbacks* allocator,
                                                  VkShaderModule* module) {
    DeviceState& d = device_of(device);
    const VkResult result = d.next.CreateShaderModule(device, info, allocator, module);
    if (result != VK_SUCCESS || !scanning_on(d)) return result;
    const SpirvScan scan = scan_spirv_bytes(info->pCode, info->codeSize);
    if (!scan.valid)
        log_message(LogLevel::kInfo,
                    "vkCreateShaderModule: SPIR-V not scanned (word %zu: %s); its dispatches are "
                    "not marked as writing through device addresses",
                    scan.error_word, scan.error.c_str());
    std::lock_guard lock(d.pipelines_mutex);
    if (scan.may_write_through_addresses() && marking_on())
        d.address_writing_modules.insert(handle_id(*module));
    if (scan.uses_ray_queries && d.sink) d.ray_query_modules.insert(handle_id(*module));
    if (scan.converts_addresses_from_memory && d.sink)
        d.structure_address_modules.insert(handle_id(*module));
    return result;
}

VKAPI_ATTR void VKAPI_CALL DestroyShaderModule(VkDevice device, VkShaderModule module,
                                               const VkAllocationCallbacks* allocator) {
    DeviceState& d = device_of(device);
    {
        std::lock_guard lock(d.pipelines_mutex);
        d.address_writing_modules.erase(handle_id(module));
        d.ray_query_modules.erase(handle_id(module));
        d.structure_address_modules.erase(handle_id(module));
    }
    d.next.DestroyShaderModule(device, module, allocator);
}

VKAPI_ATTR VkResult VKAPI_CALL CreateComputePipelines(VkDevice device, VkPipelineCache cache,
                                                      uint32_t count,
                                                      const VkComputePipelineCreateInfo* infos,
                                                      const VkAllocationCallbacks* allocator,
                                                      VkPipeline* pipelines) {
    DeviceState& d = device_of(device);
    const VkResult result =
        d.next.CreateComputePipelines(device, cache, count, infos, allocator, pipelines);
    if (!scanning_on(d)) return result;
    // VK_PIPELINE_COMPILE_REQUIRED and errors may leave some pipelines created: mark those.
    std::lock_guard lock(d.pipelines_mutex);
    for (uint32_t i = 0; i < count; ++i) {
        if (pipelines[i] == VK_NULL_HANDLE) continue;
        const ShaderStageMarks marks = shader_stage_marks(d, infos[i].stage);
        if (marks.may_write_through_addresses)
            d.address_writing_pipelines[handle_id(pipelines[i])] =
                VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT;
        if (marks.uses_ray_queries)
            d.ray_query_pipelines[handle_id(pipelines[i])] = VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT;
        if (marks.converts_addresses_from_memory)
            d.structure_address_pipelines.insert(handle_id(pipelines[i]));
    }
    return result;
}

// Graphics pipelines (vertex, tessellation, geometry, fragment, task and mesh shaders) write
// through addresses as compute shaders do. Stages taken from a pipeline library
// (VkPipelineLibraryCreateInfoKHR) are not followed.
VKAPI_ATTR VkResult VKAPI_CALL CreateGraphicsPipelines(VkDevice device, VkPipelineCache cache,
                                                       uint32_t count,
                                                       const VkGraphicsPipelineCreateInfo* infos,
                                                       const VkAllocationCallbacks* allocator,
                                                       VkPipeline* pipelines) {
    DeviceState& d = device_of(device);
    const VkResult result =
        d.next.CreateGraphicsPipelines(device, cache, count, infos, allocator, pipelines);
    if (!scanning_on(d)) return result;
    std::lock_guard lock(d.pipelines_mutex);
    for (uint32_t i = 0; i < count; ++i)
        if (pipelines[i] != VK_NULL_HANDLE)
            mark_pipeline_stages(d, handle_id(pipelines[i]), infos[i].pStages, infos[i].stageCount);
    return result;
}

VKAPI_ATTR void VKAPI_CALL DestroyPipeline(VkDevice device, VkPipeline pipeline,
                                           const VkAllocationCallbacks* allocator) {
    DeviceState& d = device_of(device);
    {
        std::lock_guard lock(d.pipelines_mutex);
        d.address_writing_pipelines.erase(handle_id(pipeline));
        d.ray_query_pipelines.erase(handle_id(pipeline));
        d.structure_address_pipelines.erase(handle_id(pipeline));
    }
    d.next.DestroyPipeline(device, pipeline, allocator);
}

}  // namespace

ShaderStageMarks shader_stage_marks(DeviceState& d, const VkPipelineShaderStageCreateInfo& stage) {
    if (stage.module != VK_NULL_HANDLE)
        return {d.address_writing_modules.count(handle_id(stage.module)) != 0,
                d.ray_query_modules.count(handle_id(stage.module)) != 0,
                d.structure_address_modules.count(handle_id(stage.module)) != 0};
    for (auto* next = static_cast<const VkBaseInStructure*>(stage.pNext); next; next = next->pNext)
        if (next->sType == VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO) {
            auto* info = reinterpret_cast<const VkShaderModuleCreateInfo*>(next);
            const SpirvScan scan = scan_spirv_bytes(info->pCode, info->codeSize);
            return {scan.may_write_through_addresses() && marking_on(),
                    scan.uses_ray_queries && d.sink, scan.converts_addresses_from_memory && d.sink};
        }
    return {};
}

void mark_pipeline_stages(DeviceState& d, uint64_t pipeline,
                          const VkPipelineShaderStageCreateInfo* stages, uint32_t stage_count) {
    VkPipelineStageFlags2 address_stages = 0, ray_stages = 0;
    bool structure_addresses = false;
    for (uint32_t s = 0; s < stage_count; ++s) {
        const ShaderStageMarks marks = shader_stage_marks(d, stages[s]);
        const VkPipelineStageFlags2 stage = pipeline_stage_of(stages[s].stage);
        if (marks.may_write_through_addresses) address_stages |= stage;
        if (marks.uses_ray_queries) ray_stages |= stage;
        structure_addresses = structure_addresses || marks.converts_addresses_from_memory;
    }
    if (address_stages) d.address_writing_pipelines[pipeline] = address_stages;
    if (ray_stages) d.ray_query_pipelines[pipeline] = ray_stages;
    if (structure_addresses) d.structure_address_pipelines.insert(pipeline);
}

VkPipelineStageFlags2 ray_query_stages(DeviceState& d, uint64_t pipeline) {
    std::lock_guard lock(d.pipelines_mutex);
    auto it = d.ray_query_pipelines.find(pipeline);
    return it == d.ray_query_pipelines.end() ? 0 : it->second;
}

bool converts_structure_addresses_from_memory(DeviceState& d, uint64_t pipeline) {
    std::lock_guard lock(d.pipelines_mutex);
    return d.structure_address_pipelines.count(pipeline) != 0;
}

VkPipelineStageFlags2 address_writing_stages(DeviceState& d, uint64_t pipeline) {
    std::lock_guard lock(d.pipelines_mutex);
    auto it = d.address_writing_pipelines.find(pipeline);
    return it == d.address_writing_pipelines.end() ? 0 : it->second;
}

PFN_vkVoidFunction pipeline_hook(const char* name) {
    if (std::strcmp(name, "vkCreateShaderModule") == 0)
        return (PFN_vkVoidFunction)CreateShaderModule;
    if (std::strcmp(name, "vkDestroyShaderModule") == 0)
        return (PFN_vkVoidFunction)DestroyShaderModule;
    if (std::strcmp(name, "vkCreateComputePipelines") == 0)
        return (PFN_vkVoidFunction)CreateComputePipelines;
    if (std::strcmp(name, "vkCreateGraphicsPipelines") == 0)
        return (PFN_vkVoidFunction)CreateGraphicsPipelines;
    if (std::strcmp(name, "vkDestroyPipeline") == 0) return (PFN_vkVoidFunction)DestroyPipeline;
    return nullptr;
}

}  // namespace clastrace::capture
