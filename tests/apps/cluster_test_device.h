// SPDX-License-Identifier: Apache-2.0
// The Vulkan set-up the headless test programs share (tests/apps, tests/capture): the first
// physical device, one compute queue with VK_NV_cluster_acceleration_structure and buffer
// device addresses enabled, a resettable command pool, and host-visible coherent buffers with
// device addresses. Nothing is destroyed behind the program's back: it calls destroy() or
// tears down itself (a program that exits mid-frame on purpose does neither). A failed call prints "<program>: <call> failed: <VkResult>" and exits with 2,
// which the tests tell apart from the layer's findings.
#pragma once

#include <clastrace/vk_cluster_abi.h>

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#define CHECK(call) ::clastrace::testapp::check_result((call), #call)

namespace clastrace::testapp {

[[noreturn]] void fail(const char* what);
void check_result(VkResult result, const char* call);
std::string hex(const void* data, size_t size);

struct Buffer {
    VkBuffer buffer = VK_NULL_HANDLE;
    VkDeviceMemory memory = VK_NULL_HANDLE;
    VkDeviceAddress address = 0;
    uint8_t* mapped = nullptr;
    VkDeviceSize size = 0;
};

struct ClusterTestDevice {
    VkInstance instance = VK_NULL_HANDLE;
    VkPhysicalDevice physicalDevice = VK_NULL_HANDLE;
    VkDevice device = VK_NULL_HANDLE;
    VkQueue queue = VK_NULL_HANDLE;
    VkQueue secondQueue = VK_NULL_HANDLE;  // queue 1 of the family, when two are asked for
    uint32_t queueFamily = 0;
    VkCommandPool pool = VK_NULL_HANDLE;
    PFN_vkCmdBuildClusterAccelerationStructureIndirectNV cmdBuildClusters = nullptr;
    PFN_vkGetClusterAccelerationStructureBuildSizesNV getBuildSizes = nullptr;
    std::vector<Buffer> buffers;  // destroyed with the device
    // Set before createDevice: enables sparseBinding (the queue family must offer sparse binds).
    bool sparseBinding = false;
    // Set before createDevice: enables VK_KHR_acceleration_structure and VK_KHR_ray_query with
    // their features (lavapipe 25 has them).
    bool rayTracing = false;
    // Set to false (with rayTracing) before createDevice: acceleration structures without
    // VK_KHR_ray_query, for a program whose capture test sees the layer enable ray queries itself.
    bool rayQuery = true;
    // Set to false before createDevice for a program that runs without the layer's extension.
    bool clusters = true;
    // Set before createDevice: a queue family that also draws, with dynamicRendering and
    // vertexPipelineStoresAndAtomics (a draw program's vertex shaders write through addresses).
    bool graphics = false;

    // applicationName nullptr: the program's own name. `extensions`: instance extensions a
    // program needs beyond ours (a window surface's). engineName nullptr: none.
    void createInstance(const char* applicationName = nullptr,
                        const std::vector<const char*>& extensions = {},
                        const char* engineName = nullptr);
    // The device lists the extension at the spec version of our ABI header.
    bool hasClusterExtension() const;
    // presentTo: a surface the queue must also present to; the device then enables VK_KHR_swapchain.
    void createDevice(bool timelineSemaphores = false, uint32_t queues = 1,
                      VkSurfaceKHR presentTo = VK_NULL_HANDLE);
    // STORAGE, TRANSFER_SRC/DST and SHADER_DEVICE_ADDRESS usage plus `usage`; every byte `fill`
    // (a marker the GPU commands must replace, where a test checks that they did).
    Buffer makeBuffer(VkDeviceSize size, VkBufferUsageFlags usage, uint8_t fill = 0);
    // A one-time-submit primary command buffer, begun.
    VkCommandBuffer beginCommands();
    void submitAndWait(VkCommandBuffer cb);
    // A pool of one query of `type`, and its 64-bit result once available.
    VkQueryPool makeQueryPool(VkQueryType type);
    uint64_t queryResult(VkQueryPool pool);
    // Waits for the device, then destroys the buffers made, the pool, the device and the instance.
    void destroy();
};

}  // namespace clastrace::testapp
