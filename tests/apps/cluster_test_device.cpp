// SPDX-License-Identifier: Apache-2.0
#include "cluster_test_device.h"

#include <clastrace/common/hex.h>

#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>

namespace clastrace::testapp {

void fail(const char* what) {
    std::fprintf(stderr, "%s: %s\n", program_invocation_short_name, what);
    std::exit(2);
}

void check_result(VkResult result, const char* call) {
    if (result == VK_SUCCESS) return;
    std::fprintf(stderr, "%s: %s failed: %d\n", program_invocation_short_name, call, int(result));
    std::exit(2);
}

std::string hex(const void* data, size_t size) {
    return common::hex_bytes({static_cast<const uint8_t*>(data), size});
}

void ClusterTestDevice::createInstance(const char* applicationName,
                                       const std::vector<const char*>& extensions,
                                       const char* engineName) {
    VkApplicationInfo app{VK_STRUCTURE_TYPE_APPLICATION_INFO,
                          nullptr,
                          applicationName ? applicationName : program_invocation_short_name,
                          1,
                          engineName,
                          0,
                          VK_API_VERSION_1_3};
    VkInstanceCreateInfo info{VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO,
                              nullptr,
                              0,
                              &app,
                              0,
                              nullptr,
                              uint32_t(extensions.size()),
                              extensions.data()};
    CHECK(vkCreateInstance(&info, nullptr, &instance));
    uint32_t count = 1;
    VkResult r = vkEnumeratePhysicalDevices(instance, &count, &physicalDevice);
    if ((r != VK_SUCCESS && r != VK_INCOMPLETE) || count == 0) fail("no physical device");
}

bool ClusterTestDevice::hasClusterExtension() const {
    uint32_t count = 0;
    vkEnumerateDeviceExtensionProperties(physicalDevice, nullptr, &count, nullptr);
    std::vector<VkExtensionProperties> all(count);
    vkEnumerateDeviceExtensionProperties(physicalDevice, nullptr, &count, all.data());
    for (const auto& e : all)
        if (std::strcmp(e.extensionName, VK_NV_CLUSTER_ACCELERATION_STRUCTURE_EXTENSION_NAME) == 0)
            return e.specVersion == VK_NV_CLUSTER_ACCELERATION_STRUCTURE_SPEC_VERSION;
    return false;
}

void ClusterTestDevice::createDevice(bool timelineSemaphores, uint32_t queues,
                                     VkSurfaceKHR presentTo) {
    uint32_t familyCount = 0;
    vkGetPhysicalDeviceQueueFamilyProperties(physicalDevice, &familyCount, nullptr);
    std::vector<VkQueueFamilyProperties> families(familyCount);
    vkGetPhysicalDeviceQueueFamilyProperties(physicalDevice, &familyCount, families.data());
    for (queueFamily = 0; queueFamily < familyCount; ++queueFamily) {
        VkBool32 presents = VK_TRUE;
        if (presentTo)
            CHECK(vkGetPhysicalDeviceSurfaceSupportKHR(physicalDevice, queueFamily, presentTo,
                                                       &presents));
        const VkQueueFlags needed = VK_QUEUE_COMPUTE_BIT |
                                    (sparseBinding ? VK_QUEUE_SPARSE_BINDING_BIT : 0) |
                                    (graphics ? VK_QUEUE_GRAPHICS_BIT : 0);
        if (presents && (families[queueFamily].queueFlags & needed) == needed) break;
    }
    if (queueFamily == familyCount)
        fail(presentTo       ? "no queue family both computes and presents to the window"
             : sparseBinding ? "no queue family both computes and binds sparse memory"
             : graphics      ? "no queue family both computes and draws"
                             : "no compute queue");
    if (queues < 1 || queues > 2 || families[queueFamily].queueCount < queues)
        fail("not enough queues in the compute family");
    const float priorities[2] = {1.0f, 1.0f};
    VkDeviceQueueCreateInfo queueInfo{
        VK_STRUCTURE_TYPE_DEVICE_QUEUE_CREATE_INFO, nullptr, 0, queueFamily, queues, priorities};
    VkPhysicalDeviceClusterAccelerationStructureFeaturesNV cluster{
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_FEATURES_NV, nullptr,
        VK_TRUE};
    VkPhysicalDeviceRayQueryFeaturesKHR rayQueryFeatures{
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_RAY_QUERY_FEATURES_KHR, clusters ? &cluster : nullptr,
        VK_TRUE};
    VkPhysicalDeviceAccelerationStructureFeaturesKHR accelerationStructure{
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_ACCELERATION_STRUCTURE_FEATURES_KHR,
        rayQuery ? static_cast<void*>(&rayQueryFeatures) : rayQueryFeatures.pNext};
    accelerationStructure.accelerationStructure = VK_TRUE;
    VkPhysicalDeviceVulkan12Features v12{};
    v12.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_2_FEATURES;
    v12.pNext = rayTracing ? static_cast<void*>(&accelerationStructure)
                           : (clusters ? static_cast<void*>(&cluster) : nullptr);
    v12.bufferDeviceAddress = VK_TRUE;
    v12.timelineSemaphore = timelineSemaphores ? VK_TRUE : VK_FALSE;
    VkPhysicalDeviceVulkan13Features v13{};
    v13.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_3_FEATURES;
    v13.pNext = &v12;
    v13.dynamicRendering = VK_TRUE;
    std::vector<const char*> extensions;
    if (clusters) extensions.push_back(VK_NV_CLUSTER_ACCELERATION_STRUCTURE_EXTENSION_NAME);
    if (presentTo) extensions.push_back(VK_KHR_SWAPCHAIN_EXTENSION_NAME);
    if (rayTracing) {
        extensions.push_back(VK_KHR_ACCELERATION_STRUCTURE_EXTENSION_NAME);
        if (rayQuery) extensions.push_back(VK_KHR_RAY_QUERY_EXTENSION_NAME);
        extensions.push_back(VK_KHR_DEFERRED_HOST_OPERATIONS_EXTENSION_NAME);
    }
    VkPhysicalDeviceFeatures core{};
    core.sparseBinding = sparseBinding ? VK_TRUE : VK_FALSE;
    core.vertexPipelineStoresAndAtomics = graphics ? VK_TRUE : VK_FALSE;
    VkDeviceCreateInfo info{VK_STRUCTURE_TYPE_DEVICE_CREATE_INFO,
                            graphics ? static_cast<void*>(&v13) : static_cast<void*>(&v12),
                            0,
                            1,
                            &queueInfo,
                            0,
                            nullptr,
                            uint32_t(extensions.size()),
                            extensions.data(),
                            &core};
    CHECK(vkCreateDevice(physicalDevice, &info, nullptr, &device));
    vkGetDeviceQueue(device, queueFamily, 0, &queue);
    if (queues == 2) vkGetDeviceQueue(device, queueFamily, 1, &secondQueue);
    VkCommandPoolCreateInfo poolInfo{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO, nullptr,
                                     VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT, queueFamily};
    CHECK(vkCreateCommandPool(device, &poolInfo, nullptr, &pool));
    if (!clusters) return;
    cmdBuildClusters = (PFN_vkCmdBuildClusterAccelerationStructureIndirectNV)
        vkGetDeviceProcAddr(device, "vkCmdBuildClusterAccelerationStructureIndirectNV");
    getBuildSizes = (PFN_vkGetClusterAccelerationStructureBuildSizesNV)
        vkGetDeviceProcAddr(device, "vkGetClusterAccelerationStructureBuildSizesNV");
    if (!cmdBuildClusters || !getBuildSizes) fail("the cluster entry points are missing");
}

Buffer ClusterTestDevice::makeBuffer(VkDeviceSize size, VkBufferUsageFlags usage, uint8_t fill) {
    Buffer b;
    b.size = size;
    VkBufferCreateInfo info{};
    info.sType = VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO;
    info.size = size;
    info.usage = usage | VK_BUFFER_USAGE_STORAGE_BUFFER_BIT | VK_BUFFER_USAGE_TRANSFER_SRC_BIT |
                 VK_BUFFER_USAGE_TRANSFER_DST_BIT | VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT;
    CHECK(vkCreateBuffer(device, &info, nullptr, &b.buffer));
    VkMemoryRequirements req;
    vkGetBufferMemoryRequirements(device, b.buffer, &req);
    VkPhysicalDeviceMemoryProperties props;
    vkGetPhysicalDeviceMemoryProperties(physicalDevice, &props);
    const VkMemoryPropertyFlags want =
        VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT;
    uint32_t type = 0;
    while (type < props.memoryTypeCount &&
           !((req.memoryTypeBits & (1u << type)) &&
             (props.memoryTypes[type].propertyFlags & want) == want))
        ++type;
    if (type == props.memoryTypeCount) fail("no host-visible coherent memory");
    VkMemoryAllocateFlagsInfo flags{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_FLAGS_INFO, nullptr,
                                    VK_MEMORY_ALLOCATE_DEVICE_ADDRESS_BIT, 0};
    VkMemoryAllocateInfo alloc{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO, &flags, req.size, type};
    CHECK(vkAllocateMemory(device, &alloc, nullptr, &b.memory));
    CHECK(vkBindBufferMemory(device, b.buffer, b.memory, 0));
    VkBufferDeviceAddressInfo addressInfo{VK_STRUCTURE_TYPE_BUFFER_DEVICE_ADDRESS_INFO, nullptr,
                                          b.buffer};
    b.address = vkGetBufferDeviceAddress(device, &addressInfo);
    void* mapped = nullptr;
    CHECK(vkMapMemory(device, b.memory, 0, VK_WHOLE_SIZE, 0, &mapped));
    b.mapped = static_cast<uint8_t*>(mapped);
    std::memset(b.mapped, fill, size);
    buffers.push_back(b);
    return b;
}

VkCommandBuffer ClusterTestDevice::beginCommands() {
    VkCommandBufferAllocateInfo info{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO, nullptr, pool,
                                     VK_COMMAND_BUFFER_LEVEL_PRIMARY, 1};
    VkCommandBuffer cb;
    CHECK(vkAllocateCommandBuffers(device, &info, &cb));
    VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO, nullptr,
                                   VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT, nullptr};
    CHECK(vkBeginCommandBuffer(cb, &begin));
    return cb;
}

VkQueryPool ClusterTestDevice::makeQueryPool(VkQueryType type) {
    VkQueryPoolCreateInfo info{VK_STRUCTURE_TYPE_QUERY_POOL_CREATE_INFO};
    info.queryType = type;
    info.queryCount = 1;
    VkQueryPool pool;
    CHECK(vkCreateQueryPool(device, &info, nullptr, &pool));
    return pool;
}

uint64_t ClusterTestDevice::queryResult(VkQueryPool pool) {
    uint64_t value = 0;
    CHECK(vkGetQueryPoolResults(device, pool, 0, 1, sizeof value, &value, sizeof value,
                                VK_QUERY_RESULT_64_BIT | VK_QUERY_RESULT_WAIT_BIT));
    return value;
}

void ClusterTestDevice::submitAndWait(VkCommandBuffer cb) {
    CHECK(vkEndCommandBuffer(cb));
    VkFenceCreateInfo fenceInfo{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO, nullptr, 0};
    VkFence fence;
    CHECK(vkCreateFence(device, &fenceInfo, nullptr, &fence));
    VkSubmitInfo submit{};
    submit.sType = VK_STRUCTURE_TYPE_SUBMIT_INFO;
    submit.commandBufferCount = 1;
    submit.pCommandBuffers = &cb;
    CHECK(vkQueueSubmit(queue, 1, &submit, fence));
    CHECK(vkWaitForFences(device, 1, &fence, VK_TRUE, 30ull * 1000 * 1000 * 1000));
    vkDestroyFence(device, fence, nullptr);
}

void ClusterTestDevice::destroy() {
    if (device) {
        vkDeviceWaitIdle(device);
        for (auto& b : buffers) {
            vkDestroyBuffer(device, b.buffer, nullptr);
            vkUnmapMemory(device, b.memory);
            vkFreeMemory(device, b.memory, nullptr);
        }
        vkDestroyCommandPool(device, pool, nullptr);
        vkDestroyDevice(device, nullptr);
    }
    if (instance) vkDestroyInstance(instance, nullptr);
    buffers.clear();
    pool = VK_NULL_HANDLE;
    device = VK_NULL_HANDLE;
    instance = VK_NULL_HANDLE;
}

}  // namespace clastrace::testapp
