// SPDX-License-Identifier: Apache-2.0
// The Vulkan objects the sample needs: one instance, one device with the cluster extension
// and buffer device addresses, one queue, and host-visible buffers that know their address.
// Failures throw VulkanError naming the call and its VkResult.
#pragma once

#include <clastrace/vk_cluster_abi.h>

#include <cstdint>
#include <mutex>
#include <stdexcept>
#include <string>

namespace cluster_scene {

struct VulkanError : std::runtime_error {
    using std::runtime_error::runtime_error;
};
// The device does not offer VK_NV_cluster_acceleration_structure (run it under the layer).
struct MissingExtension : std::runtime_error {
    using std::runtime_error::runtime_error;
};

void check(VkResult result, const char* call);
#define CLUSTER_SCENE_CHECK(call) ::cluster_scene::check((call), #call)

// A buffer in its own host-visible, coherent allocation. `address` is `offset` bytes into
// the VkBuffer, aligned as asked (the extension wants 128 or 256 for objects and scratch).
struct Buffer {
    VkBuffer buffer = VK_NULL_HANDLE;
    VkDeviceMemory memory = VK_NULL_HANDLE;
    VkDeviceSize offset = 0;
    VkDeviceSize size = 0;
    VkDeviceAddress address = 0;
    uint8_t* mapped = nullptr;  // at `offset`
};

class VulkanContext {
public:
    VulkanContext();
    ~VulkanContext();
    VulkanContext(const VulkanContext&) = delete;
    VulkanContext& operator=(const VulkanContext&) = delete;

    VkDevice device() const { return device_; }
    uint32_t queueFamily() const { return queueFamily_; }
    uint32_t queueCount() const { return queueCount_; }
    std::string deviceName() const { return deviceName_; }
    const VkPhysicalDeviceClusterAccelerationStructurePropertiesNV& clusterProperties() const {
        return properties_;
    }

    PFN_vkCmdBuildClusterAccelerationStructureIndirectNV cmdBuildClusters = nullptr;
    PFN_vkGetClusterAccelerationStructureBuildSizesNV getBuildSizes = nullptr;

    // `size` usable bytes at an `alignment`-aligned device address, filled with `fill`.
    Buffer createBuffer(VkDeviceSize size, VkBufferUsageFlags usage, VkDeviceSize alignment = 16,
                        uint8_t fill = 0);
    void destroyBuffer(Buffer& buffer);

    // Submits one command buffer to queue `index % queueCount()` and waits for it. Thread-safe:
    // a queue is externally synchronized, so submissions to it take that queue's lock.
    void submitAndWait(VkCommandBuffer commandBuffer, uint32_t index = 0);

private:
    VkInstance instance_ = VK_NULL_HANDLE;
    VkPhysicalDevice physicalDevice_ = VK_NULL_HANDLE;
    VkDevice device_ = VK_NULL_HANDLE;
    uint32_t queueFamily_ = 0;
    uint32_t queueCount_ = 1;
    VkQueue queues_[2] = {VK_NULL_HANDLE, VK_NULL_HANDLE};
    std::mutex queueLocks_[2];
    std::string deviceName_;
    VkPhysicalDeviceMemoryProperties memoryProperties_{};
    VkPhysicalDeviceClusterAccelerationStructurePropertiesNV properties_{};
};

}  // namespace cluster_scene
