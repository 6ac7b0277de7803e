// SPDX-License-Identifier: Apache-2.0
// Which compute pipelines may write through buffer device addresses: vkCreateShaderModule scans
// the SPIR-V (spirv_scan.h), vkCreateComputePipelines marks a pipeline whose shader stage uses a
// marked module (or a VkShaderModuleCreateInfo chained to the stage, as maintenance5 allows),
// and the dispatch hooks (layer_commands.cpp) ask `pipeline_may_write_addresses`.
#include "layer_state.h"

#include "clastrace/capture/spirv_scan.h"

#include <cstring>

namespace clastrace::capture {
namespace {

DeviceState& device_of(VkDevice device) { return *find_device(dispatch_key(device)); }

bool stage_may_write_addresses(DeviceState& d, const VkPipelineShaderStageCreateInfo& stage) {
    if (stage.module != VK_NULL_HANDLE)
        return d.address_writing_modules.count(handle_id(stage.module)) != 0;
    for (auto* next = static_cast<const VkBaseInStructure*>(stage.pNext); next; next = next->pNext)
        if (next->sType == VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO) {
            auto* info = reinterpret_cast<const VkShaderModuleCreateInfo*>(next);
            return scan_spirv_bytes(info->pCode, info->codeSize).may_write_through_addresses();
        }
    return false;
}

VKAPI_ATTR VkResult VKAPI_CALL CreateShaderModule(VkDevice device,
                                                  const VkShaderModuleCreateInfo* info,
                                                  const VkAllocationCallbacks* allocator,
                                                  VkShaderModule* module) {
    DeviceState& d = device_of(device);
    const VkResult result = d.next.CreateShaderModule(device, info, allocator, module);
    if (result != VK_SUCCESS) return result;
    const SpirvScan scan = scan_spirv_bytes(info->pCode, info->codeSize);
    if (!scan.valid)
        log_message(LogLevel::kInfo,
                    "vkCreateShaderModule: SPIR-V not scanned (word %zu: %s); its dispatches are "
                    "not marked as writing through device addresses",
                    scan.error_word, scan.error.c_str());
    if (scan.may_write_through_addresses()) {
        std::lock_guard lock(d.pipelines_mutex);
        d.address_writing_modules.insert(handle_id(*module));
    }
    return result;
}

VKAPI_ATTR void VKAPI_CALL DestroyShaderModule(VkDevice device, VkShaderModule module,
                                               const VkAllocationCallbacks* allocator) {
    DeviceState& d = device_of(device);
    {
        std::lock_guard lock(d.pipelines_mutex);
        d.address_writing_modules.erase(handle_id(module));
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
    // VK_PIPELINE_COMPILE_REQUIRED and errors may leave some pipelines created: mark those.
    std::lock_guard lock(d.pipelines_mutex);
    for (uint32_t i = 0; i < count; ++i)
        if (pipelines[i] != VK_NULL_HANDLE && stage_may_write_addresses(d, infos[i].stage))
            d.address_writing_pipelines.insert(handle_id(pipelines[i]));
    return result;
}

VKAPI_ATTR void VKAPI_CALL DestroyPipeline(VkDevice device, VkPipeline pipeline,
                                           const VkAllocationCallbacks* allocator) {
    DeviceState& d = device_of(device);
    {
        std::lock_guard lock(d.pipelines_mutex);
        d.address_writing_pipelines.erase(handle_id(pipeline));
    }
    d.next.DestroyPipeline(device, pipeline, allocator);
}

}  // namespace

bool pipeline_may_write_addresses(DeviceState& d, uint64_t pipeline) {
    std::lock_guard lock(d.pipelines_mutex);
    return d.address_writing_pipelines.count(pipeline) != 0;
}

PFN_vkVoidFunction pipeline_hook(const char* name) {
    if (std::strcmp(name, "vkCreateShaderModule") == 0)
        return (PFN_vkVoidFunction)CreateShaderModule;
    if (std::strcmp(name, "vkDestroyShaderModule") == 0)
        return (PFN_vkVoidFunction)DestroyShaderModule;
    if (std::strcmp(name, "vkCreateComputePipelines") == 0)
        return (PFN_vkVoidFunction)CreateComputePipelines;
    if (std::strcmp(name, "vkDestroyPipeline") == 0) return (PFN_vkVoidFunction)DestroyPipeline;
    return nullptr;
}

}  // namespace clastrace::capture
