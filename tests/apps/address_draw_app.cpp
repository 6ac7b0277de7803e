// SPDX-License-Identifier: Apache-2.0
// A headless draw program for the capture tests of draws that write through buffer device
// addresses (capture/src/spirv_draws.cpp): two graphics pipelines with rasterizer discard and
// no attachment (dynamic rendering), one whose vertex shader writes each vertex index through
// an address in a push constant (shaders/address_draw.vert), one whose shader reaches no memory
// (shaders/plain_draw.vert). One command buffer draws 4 vertices with each; after the fence the
// program checks the 4 words the first wrote. Exit 0 and "ok" when they are 1..4; 2 otherwise.
#include <vulkan/vulkan.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>

// The shaders' SPIR-V as uint32_t arrays, compiled at build time (tests/apps/CMakeLists.txt).
#include "address_draw_vert.h"  // kAddressDrawVert
#include "plain_draw_vert.h"    // kPlainDrawVert

namespace {

void check(VkResult result, const char* call) {
    if (result == VK_SUCCESS) return;
    std::fprintf(stderr, "address_draw_app: %s failed: %d\n", call, int(result));
    std::exit(2);
}
#define CHECK(call) check((call), #call)

struct Device {
    VkInstance instance = VK_NULL_HANDLE;
    VkPhysicalDevice physical = VK_NULL_HANDLE;
    VkDevice device = VK_NULL_HANDLE;
    VkQueue queue = VK_NULL_HANDLE;
    uint32_t family = 0;
};

Device create_device() {
    Device d;
    VkApplicationInfo app{VK_STRUCTURE_TYPE_APPLICATION_INFO};
    app.pApplicationName = "address_draw_app";
    app.apiVersion = VK_API_VERSION_1_3;
    VkInstanceCreateInfo instance_info{VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO};
    instance_info.pApplicationInfo = &app;
    CHECK(vkCreateInstance(&instance_info, nullptr, &d.instance));
    uint32_t count = 1;
    VkResult listed = vkEnumeratePhysicalDevices(d.instance, &count, &d.physical);
    if ((listed != VK_SUCCESS && listed != VK_INCOMPLETE) || count == 0) {
        std::fprintf(stderr, "address_draw_app: no Vulkan device\n");
        std::exit(2);
    }
    uint32_t families = 0;
    vkGetPhysicalDeviceQueueFamilyProperties(d.physical, &families, nullptr);
    VkQueueFamilyProperties properties[16];
    families = families > 16 ? 16 : families;
    vkGetPhysicalDeviceQueueFamilyProperties(d.physical, &families, properties);
    while (d.family < families && !(properties[d.family].queueFlags & VK_QUEUE_GRAPHICS_BIT))
        ++d.family;
    const float priority = 1.0f;
    VkDeviceQueueCreateInfo queue_info{VK_STRUCTURE_TYPE_DEVICE_QUEUE_CREATE_INFO};
    queue_info.queueFamilyIndex = d.family;
    queue_info.queueCount = 1;
    queue_info.pQueuePriorities = &priority;
    VkPhysicalDeviceVulkan13Features v13{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_3_FEATURES};
    v13.dynamicRendering = VK_TRUE;
    VkPhysicalDeviceVulkan12Features v12{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_2_FEATURES};
    v12.pNext = &v13;
    v12.bufferDeviceAddress = VK_TRUE;
    VkPhysicalDeviceFeatures2 features{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FEATURES_2};
    features.pNext = &v12;
    features.features.vertexPipelineStoresAndAtomics = VK_TRUE;
    VkDeviceCreateInfo device_info{VK_STRUCTURE_TYPE_DEVICE_CREATE_INFO};
    device_info.pNext = &features;
    device_info.queueCreateInfoCount = 1;
    device_info.pQueueCreateInfos = &queue_info;
    CHECK(vkCreateDevice(d.physical, &device_info, nullptr, &d.device));
    vkGetDeviceQueue(d.device, d.family, 0, &d.queue);
    return d;
}

struct Target {
    VkBuffer buffer = VK_NULL_HANDLE;
    VkDeviceMemory memory = VK_NULL_HANDLE;
    VkDeviceAddress address = 0;
    uint32_t* words = nullptr;
};

Target create_target(const Device& d) {
    Target t;
    VkBufferCreateInfo info{VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO};
    info.size = 256;
    info.usage = VK_BUFFER_USAGE_STORAGE_BUFFER_BIT | VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT;
    CHECK(vkCreateBuffer(d.device, &info, nullptr, &t.buffer));
    VkMemoryRequirements requirements;
    vkGetBufferMemoryRequirements(d.device, t.buffer, &requirements);
    VkPhysicalDeviceMemoryProperties memory;
    vkGetPhysicalDeviceMemoryProperties(d.physical, &memory);
    const VkMemoryPropertyFlags want =
        VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT;
    uint32_t type = 0;
    while (type < memory.memoryTypeCount &&
           (!(requirements.memoryTypeBits & (1u << type)) ||
            (memory.memoryTypes[type].propertyFlags & want) != want))
        ++type;
    VkMemoryAllocateFlagsInfo flags{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_FLAGS_INFO};
    flags.flags = VK_MEMORY_ALLOCATE_DEVICE_ADDRESS_BIT;
    VkMemoryAllocateInfo allocate{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO, &flags, requirements.size,
                                  type};
    CHECK(vkAllocateMemory(d.device, &allocate, nullptr, &t.memory));
    CHECK(vkBindBufferMemory(d.device, t.buffer, t.memory, 0));
    VkBufferDeviceAddressInfo address{VK_STRUCTURE_TYPE_BUFFER_DEVICE_ADDRESS_INFO, nullptr,
                                      t.buffer};
    t.address = vkGetBufferDeviceAddress(d.device, &address);
    void* mapped = nullptr;
    CHECK(vkMapMemory(d.device, t.memory, 0, VK_WHOLE_SIZE, 0, &mapped));
    t.words = static_cast<uint32_t*>(mapped);
    std::memset(mapped, 0, 256);
    return t;
}

VkPipeline create_pipeline(const Device& d, VkPipelineLayout layout, const uint32_t* code,
                           size_t code_size) {
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
    const Device d = create_device();
    const Target target = create_target(d);
    const VkPushConstantRange range{VK_SHADER_STAGE_VERTEX_BIT, 0, sizeof(VkDeviceAddress)};
    VkPipelineLayoutCreateInfo layout_info{VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO};
    layout_info.pushConstantRangeCount = 1;
    layout_info.pPushConstantRanges = &range;
    VkPipelineLayout layout;
    CHECK(vkCreatePipelineLayout(d.device, &layout_info, nullptr, &layout));
    const VkPipeline writing =
        create_pipeline(d, layout, kAddressDrawVert, sizeof kAddressDrawVert);
    const VkPipeline plain = create_pipeline(d, layout, kPlainDrawVert, sizeof kPlainDrawVert);

    VkCommandPoolCreateInfo pool_info{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO};
    pool_info.queueFamilyIndex = d.family;
    VkCommandPool pool;
    CHECK(vkCreateCommandPool(d.device, &pool_info, nullptr, &pool));
    VkCommandBufferAllocateInfo allocate{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO, nullptr,
                                         pool, VK_COMMAND_BUFFER_LEVEL_PRIMARY, 1};
    VkCommandBuffer cb;
    CHECK(vkAllocateCommandBuffers(d.device, &allocate, &cb));
    VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
    CHECK(vkBeginCommandBuffer(cb, &begin));
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
    CHECK(vkEndCommandBuffer(cb));
    VkFenceCreateInfo fence_info{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO};
    VkFence fence;
    CHECK(vkCreateFence(d.device, &fence_info, nullptr, &fence));
    VkSubmitInfo submit{VK_STRUCTURE_TYPE_SUBMIT_INFO};
    submit.commandBufferCount = 1;
    submit.pCommandBuffers = &cb;
    CHECK(vkQueueSubmit(d.queue, 1, &submit, fence));
    CHECK(vkWaitForFences(d.device, 1, &fence, VK_TRUE, 60ull * 1000 * 1000 * 1000));
    bool ok = true;
    for (uint32_t i = 0; i < 4; ++i) ok &= target.words[i] == i + 1;

    vkDestroyFence(d.device, fence, nullptr);
    vkDestroyCommandPool(d.device, pool, nullptr);
    vkDestroyPipeline(d.device, writing, nullptr);
    vkDestroyPipeline(d.device, plain, nullptr);
    vkDestroyPipelineLayout(d.device, layout, nullptr);
    vkUnmapMemory(d.device, target.memory);
    vkDestroyBuffer(d.device, target.buffer, nullptr);
    vkFreeMemory(d.device, target.memory, nullptr);
    vkDestroyDevice(d.device, nullptr);
    vkDestroyInstance(d.instance, nullptr);
    std::printf("%s\n", ok ? "ok" : "wrong words");
    return ok ? 0 : 2;
}
