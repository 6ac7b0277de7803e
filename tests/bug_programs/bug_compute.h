// SPDX-License-Identifier: Apache-2.0
// The bug programs' one compute pass (shaders/copy_words.comp, a GPU-driven engine's culling
// output reduced to a copy of words): its pipeline, its descriptor set over two buffers, and
// the commands that run it.
#pragma once

#include "bug_gpu.h"
#include "copy_words_comp.h"  // kCopyWordsComp: shaders/copy_words.comp

namespace bug_programs {

// The compute pipeline of copy_words.comp and the one descriptor set it binds.
struct CopyPass {
    VkDescriptorSetLayout set_layout = VK_NULL_HANDLE;
    VkPipelineLayout layout = VK_NULL_HANDLE;
    VkPipeline pipeline = VK_NULL_HANDLE;
    VkDescriptorPool pool = VK_NULL_HANDLE;
    VkDescriptorSet set = VK_NULL_HANDLE;
};

inline CopyPass make_copy_pass(Gpu& gpu, const Buffer& from, const Buffer& to) {
    CopyPass p;
    VkShaderModuleCreateInfo module_info{VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO};
    module_info.codeSize = sizeof kCopyWordsComp;
    module_info.pCode = kCopyWordsComp;
    VkShaderModule module = VK_NULL_HANDLE;
    vk_ok(vkCreateShaderModule(gpu.device, &module_info, nullptr, &module), "vkCreateShaderModule");
    VkDescriptorSetLayoutBinding bindings[2] = {};
    for (uint32_t b = 0; b < 2; ++b)
        bindings[b] = {b, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, 1, VK_SHADER_STAGE_COMPUTE_BIT};
    VkDescriptorSetLayoutCreateInfo set_info{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_CREATE_INFO};
    set_info.bindingCount = 2;
    set_info.pBindings = bindings;
    vk_ok(vkCreateDescriptorSetLayout(gpu.device, &set_info, nullptr, &p.set_layout),
          "vkCreateDescriptorSetLayout");
    const VkPushConstantRange words{VK_SHADER_STAGE_COMPUTE_BIT, 0, sizeof(uint32_t)};
    VkPipelineLayoutCreateInfo layout_info{VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO};
    layout_info.setLayoutCount = 1;
    layout_info.pSetLayouts = &p.set_layout;
    layout_info.pushConstantRangeCount = 1;
    layout_info.pPushConstantRanges = &words;
    vk_ok(vkCreatePipelineLayout(gpu.device, &layout_info, nullptr, &p.layout),
          "vkCreatePipelineLayout");
    VkComputePipelineCreateInfo pipeline_info{VK_STRUCTURE_TYPE_COMPUTE_PIPELINE_CREATE_INFO};
    pipeline_info.stage = {VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO};
    pipeline_info.stage.stage = VK_SHADER_STAGE_COMPUTE_BIT;
    pipeline_info.stage.module = module;
    pipeline_info.stage.pName = "main";
    pipeline_info.layout = p.layout;
    vk_ok(vkCreateComputePipelines(gpu.device, VK_NULL_HANDLE, 1, &pipeline_info, nullptr,
                                   &p.pipeline),
          "vkCreateComputePipelines");
    vkDestroyShaderModule(gpu.device, module, nullptr);
    const VkDescriptorPoolSize two{VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, 2};
    VkDescriptorPoolCreateInfo pool_info{VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO};
    pool_info.maxSets = 1;
    pool_info.poolSizeCount = 1;
    pool_info.pPoolSizes = &two;
    vk_ok(vkCreateDescriptorPool(gpu.device, &pool_info, nullptr, &p.pool),
          "vkCreateDescriptorPool");
    VkDescriptorSetAllocateInfo alloc{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_ALLOCATE_INFO};
    alloc.descriptorPool = p.pool;
    alloc.descriptorSetCount = 1;
    alloc.pSetLayouts = &p.set_layout;
    vk_ok(vkAllocateDescriptorSets(gpu.device, &alloc, &p.set), "vkAllocateDescriptorSets");
    const VkDescriptorBufferInfo targets[2] = {{from.buffer, 0, from.size},
                                               {to.buffer, 0, to.size}};
    VkWriteDescriptorSet writes[2] = {};
    for (uint32_t b = 0; b < 2; ++b) {
        writes[b] = {VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET};
        writes[b].dstSet = p.set;
        writes[b].dstBinding = b;
        writes[b].descriptorCount = 1;
        writes[b].descriptorType = VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
        writes[b].pBufferInfo = &targets[b];
    }
    vkUpdateDescriptorSets(gpu.device, 2, writes, 0, nullptr);
    return p;
}

inline void destroy(Gpu& gpu, CopyPass& p) {
    vkDestroyDescriptorPool(gpu.device, p.pool, nullptr);
    vkDestroyPipeline(gpu.device, p.pipeline, nullptr);
    vkDestroyPipelineLayout(gpu.device, p.layout, nullptr);
    vkDestroyDescriptorSetLayout(gpu.device, p.set_layout, nullptr);
}


// Binds `p` and dispatches it over `words` words.
inline void record_copy(VkCommandBuffer cb, const CopyPass& p, uint32_t words) {
    vkCmdBindPipeline(cb, VK_PIPELINE_BIND_POINT_COMPUTE, p.pipeline);
    vkCmdBindDescriptorSets(cb, VK_PIPELINE_BIND_POINT_COMPUTE, p.layout, 0, 1, &p.set, 0, nullptr);
    vkCmdPushConstants(cb, p.layout, VK_SHADER_STAGE_COMPUTE_BIT, 0, sizeof words, &words);
    vkCmdDispatch(cb, (words + 63) / 64, 1, 1);
}

}  // namespace bug_programs
