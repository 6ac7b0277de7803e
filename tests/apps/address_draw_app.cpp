// SPDX-License-Identifier: Apache-2.0
// A headless draw program for the capture tests of draws that write through buffer device
// addresses (capture/src/spirv_draws.cpp): two graphics pipelines with rasterizer discard and
// no attachment (dynamic rendering), one whose vertex shader writes each vertex index through
// an address in a push constant (shaders/address_draw.vert), one whose shader reaches no memory
// (shaders/plain_draw.vert). One command buffer draws 4 vertices with each; after the fence the
// program checks the 4 words the first wrote. Exit 0 and "ok" when they are 1..4; 2 otherwise.
#include "cluster_test_device.h"

#include <cstdint>
#include <cstdio>

// The shaders' SPIR-V as uint32_t arrays, compiled at build time (tests/apps/CMakeLists.txt).
#include "address_draw_vert.h"  // kAddressDrawVert
#include "plain_draw_vert.h"    // kPlainDrawVert

namespace {

using clastrace::testapp::Buffer;
using clastrace::testapp::ClusterTestDevice;

VkPipeline create_pipeline(const ClusterTestDevice& d, VkPipelineLayout layout,
                           const uint32_t* code, size_t code_size) {
    VkShaderModuleCreateInfo module_info{VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO};
    module_info.codeSize = code_size;
    module_info.pCode = code;
    VkShaderModule module;
    CHECK(vkCreateShaderModule(d.device, &module_info, nullptr, &module));
    VkPipelineShaderStageCreateInfo stage{VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO};
    stage.stage = VK_SHADER_STAGE_VERTEX_BIT;
    stage.module = module;
    stage.pName = "main";
    VkPipelineVertexInputStateCreateInfo vertex_input{
        VK_STRUCTURE_TYPE_PIPELINE_VERTEX_INPUT_STATE_CREATE_INFO};
    VkPipelineInputAssemblyStateCreateInfo assembly{
        VK_STRUCTURE_TYPE_PIPELINE_INPUT_ASSEMBLY_STATE_CREATE_INFO};
    assembly.topology = VK_PRIMITIVE_TOPOLOGY_POINT_LIST;
    VkPipelineRasterizationStateCreateInfo raster{
        VK_STRUCTURE_TYPE_PIPELINE_RASTERIZATION_STATE_CREATE_INFO};
    raster.rasterizerDiscardEnable = VK_TRUE;  // vertices only: no viewport, no attachment
    raster.lineWidth = 1.0f;
    VkPipelineRenderingCreateInfo rendering{VK_STRUCTURE_TYPE_PIPELINE_RENDERING_CREATE_INFO};
    VkGraphicsPipelineCreateInfo info{VK_STRUCTURE_TYPE_GRAPHICS_PIPELINE_CREATE_INFO};
    info.pNext = &rendering;
    info.stageCount = 1;
    info.pStages = &stage;
    info.pVertexInputState = &vertex_input;
    info.pInputAssemblyState = &assembly;
    info.pRasterizationState = &raster;
    info.layout = layout;
    VkPipeline pipeline;
    CHECK(vkCreateGraphicsPipelines(d.device, VK_NULL_HANDLE, 1, &info, nullptr, &pipeline));
    vkDestroyShaderModule(d.device, module, nullptr);
    return pipeline;
}

}  // namespace

int main() {
    ClusterTestDevice d;
    d.clusters = false;
    d.graphics = true;
    d.createInstance();
    d.createDevice();
    const Buffer target = d.makeBuffer(256, 0);
    const auto* words = reinterpret_cast<const uint32_t*>(target.mapped);
    const VkPushConstantRange range{VK_SHADER_STAGE_VERTEX_BIT, 0, sizeof(VkDeviceAddress)};
    VkPipelineLayoutCreateInfo layout_info{VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO};
    layout_info.pushConstantRangeCount = 1;
    layout_info.pPushConstantRanges = &range;
    VkPipelineLayout layout;
    CHECK(vkCreatePipelineLayout(d.device, &layout_info, nullptr, &layout));
    const VkPipeline writing =
        create_pipeline(d, layout, kAddressDrawVert, sizeof kAddressDrawVert);
    const VkPipeline plain = create_pipeline(d, layout, kPlainDrawVert, sizeof kPlainDrawVert);

    VkCommandBuffer cb = d.beginCommands();
    VkRenderingInfo rendering{VK_STRUCTURE_TYPE_RENDERING_INFO};
    rendering.renderArea = {{0, 0}, {1, 1}};
    rendering.layerCount = 1;
    vkCmdBeginRendering(cb, &rendering);
    vkCmdBindPipeline(cb, VK_PIPELINE_BIND_POINT_GRAPHICS, writing);
    vkCmdPushConstants(cb, layout, VK_SHADER_STAGE_VERTEX_BIT, 0, sizeof target.address,
                       &target.address);
    vkCmdDraw(cb, 4, 1, 0, 0);
    vkCmdBindPipeline(cb, VK_PIPELINE_BIND_POINT_GRAPHICS, plain);
    vkCmdDraw(cb, 4, 1, 0, 0);
    vkCmdEndRendering(cb);
    VkMemoryBarrier to_host{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr, VK_ACCESS_SHADER_WRITE_BIT,
                            VK_ACCESS_HOST_READ_BIT};
    vkCmdPipelineBarrier(cb, VK_PIPELINE_STAGE_VERTEX_SHADER_BIT, VK_PIPELINE_STAGE_HOST_BIT, 0, 1,
                         &to_host, 0, nullptr, 0, nullptr);
    d.submitAndWait(cb);
    bool ok = true;
    for (uint32_t i = 0; i < 4; ++i) ok &= words[i] == i + 1;

    vkDestroyPipeline(d.device, writing, nullptr);
    vkDestroyPipeline(d.device, plain, nullptr);
    vkDestroyPipelineLayout(d.device, layout, nullptr);
    d.destroy();
    std::printf("%s\n", ok ? "ok" : "wrong words");
    return ok ? 0 : 2;
}
