// SPDX-License-Identifier: Apache-2.0
#include "vulkan_context.h"

#include <algorithm>
#include <cstring>
#include <vector>

namespace cluster_scene {

void check(VkResult result, const char* call) {
    if (result != VK_SUCCESS)
        throw VulkanError(std::string(call) + " failed with VkResult " +
                          std::to_string(int(result)));
}

VulkanContext::VulkanContext() {
    VkApplicationInfo app{VK_STRUCTURE_TYPE_APPLICATION_INFO,
                          nullptr,
                          "cluster_scene",
                          1,
                          nullptr,
                          0,
                          VK_API_VERSION_1_3};
    VkInstanceCreateInfo instanceInfo{
        VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO, nullptr, 0, &app, 0, nullptr, 0, nullptr};
    CLUSTER_SCENE_CHECK(vkCreateInstance(&instanceInfo, nullptr, &instance_));
    uint32_t count = 1;
    VkResult r = vkEnumeratePhysicalDevices(instance_, &count, &physicalDevice_);
    if ((r != VK_SUCCESS && r != VK_INCOMPLETE) || count == 0)
        throw VulkanError("no Vulkan physical device");

    VkPhysicalDeviceProperties2 properties2{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2,
                                            &properties_,
                                            {}};
    properties_.sType =
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_PROPERTIES_NV;
    vkGetPhysicalDeviceProperties2(physicalDevice_, &properties2);
    properties_.pNext = nullptr;
    deviceName_ = properties2.properties.deviceName;
    vkGetPhysicalDeviceMemoryProperties(physicalDevice_, &memoryProperties_);

    uint32_t extensionCount = 0;
    vkEnumerateDeviceExtensionProperties(physicalDevice_, nullptr, &extensionCount, nullptr);
    std::vector<VkExtensionProperties> extensions(extensionCount);
    vkEnumerateDeviceExtensionProperties(physicalDevice_, nullptr, &extensionCount,
                                         extensions.data());
    bool found = false;
    for (const auto& e : extensions)
        found |=
            std::strcmp(e.extensionName, VK_NV_CLUSTER_ACCELERATION_STRUCTURE_EXTENSION_NAME) == 0;
    if (!found)
        throw MissingExtension(
            deviceName_ + " does not offer " VK_NV_CLUSTER_ACCELERATION_STRUCTURE_EXTENSION_NAME
                          " (run it under VK_LAYER_CLASTRACE_capture, e.g. `clastrace capture -o "
                          "OUT.clt -- cluster_scene`, "
                          "which serves the extension on any driver)");

    // The first family with compute; up to two of its queues.
    uint32_t familyCount = 0;
    vkGetPhysicalDeviceQueueFamilyProperties(physicalDevice_, &familyCount, nullptr);
    std::vector<VkQueueFamilyProperties> families(familyCount);
    vkGetPhysicalDeviceQueueFamilyProperties(physicalDevice_, &familyCount, families.data());
    for (queueFamily_ = 0; queueFamily_ < familyCount; ++queueFamily_)
        if (families[queueFamily_].queueFlags & VK_QUEUE_COMPUTE_BIT) break;
    if (queueFamily_ == familyCount) throw VulkanError(deviceName_ + " has no compute queue");
    queueCount_ = std::min(2u, families[queueFamily_].queueCount);
    const float priorities[2] = {1.0f, 1.0f};
    VkDeviceQueueCreateInfo queueInfo{VK_STRUCTURE_TYPE_DEVICE_QUEUE_CREATE_INFO,
                                      nullptr,
                                      0,
                                      queueFamily_,
                                      queueCount_,
                                      priorities};
    VkPhysicalDeviceClusterAccelerationStructureFeaturesNV cluster{
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_FEATURES_NV, nullptr,
        VK_TRUE};
    VkPhysicalDeviceVulkan12Features v12{};
    v12.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_2_FEATURES;
    v12.pNext = &cluster;
    v12.bufferDeviceAddress = VK_TRUE;
    const char* extension = VK_NV_CLUSTER_ACCELERATION_STRUCTURE_EXTENSION_NAME;
    VkDeviceCreateInfo deviceInfo{VK_STRUCTURE_TYPE_DEVICE_CREATE_INFO,
                                  &v12,
                                  0,
                                  1,
                                  &queueInfo,
                                  0,
                                  nullptr,
                                  1,
                                  &extension,
                                  nullptr};
    CLUSTER_SCENE_CHECK(vkCreateDevice(physicalDevice_, &deviceInfo, nullptr, &device_));
    for (uint32_t i = 0; i < queueCount_; ++i)
        vkGetDeviceQueue(device_, queueFamily_, i, &queues_[i]);
    cmdBuildClusters = (PFN_vkCmdBuildClusterAccelerationStructureIndirectNV)
        vkGetDeviceProcAddr(device_, "vkCmdBuildClusterAccelerationStructureIndirectNV");
    getBuildSizes = (PFN_vkGetClusterAccelerationStructureBuildSizesNV)
        vkGetDeviceProcAddr(device_, "vkGetClusterAccelerationStructureBuildSizesNV");
    if (!cmdBuildClusters || !getBuildSizes)
        throw VulkanError("the device lists " VK_NV_CLUSTER_ACCELERATION_STRUCTURE_EXTENSION_NAME
                          " but not its entry points");
}

VulkanContext::~VulkanContext() {
    if (device_) {
        vkDeviceWaitIdle(device_);
        vkDestroyDevice(device_, nullptr);
    }
    if (instance_) vkDestroyInstance(instance_, nullptr);
}

Buffer VulkanContext::createBuffer(VkDeviceSize size, VkBufferUsageFlags usage,
                                   VkDeviceSize alignment, uint8_t fill) {
    Buffer b;
    b.size = size;
    VkBufferCreateInfo info{};
    info.sType = VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO;
    info.size = size + alignment;
    info.usage = usage | VK_BUFFER_USAGE_TRANSFER_SRC_BIT | VK_BUFFER_USAGE_TRANSFER_DST_BIT |
                 VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT;
    CLUSTER_SCENE_CHECK(vkCreateBuffer(device_, &info, nullptr, &b.buffer));
    VkMemoryRequirements requirements;
    vkGetBufferMemoryRequirements(device_, b.buffer, &requirements);
    const VkMemoryPropertyFlags want =
        VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT;
    uint32_t type = 0;
    for (; type < memoryProperties_.memoryTypeCount; ++type)
        if ((requirements.memoryTypeBits & (1u << type)) &&
            (memoryProperties_.memoryTypes[type].propertyFlags & want) == want)
            break;
    if (type == memoryProperties_.memoryTypeCount)
        throw VulkanError(deviceName_ + " has no host-visible coherent memory");
    VkMemoryAllocateFlagsInfo flags{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_FLAGS_INFO, nullptr,
                                    VK_MEMORY_ALLOCATE_DEVICE_ADDRESS_BIT, 0};
    VkMemoryAllocateInfo allocate{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO, &flags, requirements.size,
                                  type};
    CLUSTER_SCENE_CHECK(vkAllocateMemory(device_, &allocate, nullptr, &b.memory));
    CLUSTER_SCENE_CHECK(vkBindBufferMemory(device_, b.buffer, b.memory, 0));
    VkBufferDeviceAddressInfo addressInfo{VK_STRUCTURE_TYPE_BUFFER_DEVICE_ADDRESS_INFO, nullptr,
                                          b.buffer};
    const VkDeviceAddress base = vkGetBufferDeviceAddress(device_, &addressInfo);
    b.offset = (alignment - base % alignment) % alignment;
    b.address = base + b.offset;
    void* mapped = nullptr;
    CLUSTER_SCENE_CHECK(vkMapMemory(device_, b.memory, 0, VK_WHOLE_SIZE, 0, &mapped));
    b.mapped = static_cast<uint8_t*>(mapped) + b.offset;
    std::memset(mapped, fill, size + alignment);
    return b;
}

void VulkanContext::destroyBuffer(Buffer& b) {
    if (b.buffer) vkDestroyBuffer(device_, b.buffer, nullptr);
    if (b.memory) {
        vkUnmapMemory(device_, b.memory);
        vkFreeMemory(device_, b.memory, nullptr);
    }
    b = {};
}

void VulkanContext::submitAndWait(VkCommandBuffer commandBuffer, uint32_t index) {
    const uint32_t queue = index % queueCount_;
    VkFenceCreateInfo fenceInfo{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO, nullptr, 0};
    VkFence fence;
    CLUSTER_SCENE_CHECK(vkCreateFence(device_, &fenceInfo, nullptr, &fence));
    VkSubmitInfo submit{};
    submit.sType = VK_STRUCTURE_TYPE_SUBMIT_INFO;
    submit.commandBufferCount = 1;
    submit.pCommandBuffers = &commandBuffer;
    {
        std::lock_guard lock(queueLocks_[queue]);
        CLUSTER_SCENE_CHECK(vkQueueSubmit(queues_[queue], 1, &submit, fence));
    }
    const VkResult waited =
        vkWaitForFences(device_, 1, &fence, VK_TRUE, 60ull * 1000 * 1000 * 1000);
    vkDestroyFence(device_, fence, nullptr);
    CLUSTER_SCENE_CHECK(waited);
}

}  // namespace cluster_scene
