// SPDX-License-Identifier: Apache-2.0
// VK_LAYER_CLASTRACE_test_two_queues: a test layer, loaded below the capture layer, that gives
// lavapipe's single-queue family a second queue. Queue 1 is a handle of this layer's own whose
// submissions go to the driver's one queue, so the capture layer above sees two queues and a
// simultaneous-use command buffer submitted to both, as on a GPU with several queues.
#include <vulkan/vk_layer.h>
#include <vulkan/vulkan.h>

#include <cstring>
#include <mutex>
#include <unordered_map>
#include <vector>

namespace {

struct Shim {
    std::mutex mutex;
    PFN_vkGetInstanceProcAddr nextGipa = nullptr;
    PFN_vkGetDeviceProcAddr nextGdpa = nullptr;
    PFN_vkGetPhysicalDeviceQueueFamilyProperties nextFamilies = nullptr;
    PFN_vkGetPhysicalDeviceQueueFamilyProperties2 nextFamilies2 = nullptr;
    PFN_vkGetDeviceQueue nextGetQueue = nullptr;
    PFN_vkQueueSubmit nextSubmit = nullptr;
    PFN_vkQueueSubmit2 nextSubmit2 = nullptr;
    PFN_vkQueueWaitIdle nextWaitIdle = nullptr;
    VkQueue real = VK_NULL_HANDLE;
    std::unordered_map<VkQueue, VkQueue> fakes;  // queue 1 -> the driver's queue 0
};
Shim& shim() {
    static Shim s;
    return s;
}

VkQueue realQueue(VkQueue q) {
    std::lock_guard lock(shim().mutex);
    auto it = shim().fakes.find(q);
    return it == shim().fakes.end() ? q : it->second;
}

template <class Info>
Info* layerLink(const void* pNext, VkStructureType type) {
    auto* info = (Info*)pNext;
    while (info && !(info->sType == type && info->function == VK_LAYER_LINK_INFO))
        info = (Info*)info->pNext;
    return info;
}

VKAPI_ATTR VkResult VKAPI_CALL CreateInstance(const VkInstanceCreateInfo* pCreateInfo,
                                              const VkAllocationCallbacks* pAllocator,
                                              VkInstance* pInstance) {
    auto* link =
        layerLink<VkLayerInstanceCreateInfo>(pCreateInfo->pNext,
                                             VK_STRUCTURE_TYPE_LOADER_INSTANCE_CREATE_INFO);
    if (!link) return VK_ERROR_INITIALIZATION_FAILED;
    shim().nextGipa = link->u.pLayerInfo->pfnNextGetInstanceProcAddr;
    link->u.pLayerInfo = link->u.pLayerInfo->pNext;
    auto create = (PFN_vkCreateInstance)shim().nextGipa(VK_NULL_HANDLE, "vkCreateInstance");
    VkResult r = create(pCreateInfo, pAllocator, pInstance);
    if (r != VK_SUCCESS) return r;
    shim().nextFamilies = (PFN_vkGetPhysicalDeviceQueueFamilyProperties)shim().nextGipa(
        *pInstance, "vkGetPhysicalDeviceQueueFamilyProperties");
    shim().nextFamilies2 = (PFN_vkGetPhysicalDeviceQueueFamilyProperties2)shim().nextGipa(
        *pInstance, "vkGetPhysicalDeviceQueueFamilyProperties2");
    return r;
}

VKAPI_ATTR void VKAPI_CALL GetPhysicalDeviceQueueFamilyProperties(VkPhysicalDevice pd,
                                                                  uint32_t* count,
                                                                  VkQueueFamilyProperties* props) {
    shim().nextFamilies(pd, count, props);
    if (props && *count) props[0].queueCount = 2;
}
VKAPI_ATTR void VKAPI_CALL GetPhysicalDeviceQueueFamilyProperties2(
    VkPhysicalDevice pd, uint32_t* count, VkQueueFamilyProperties2* props) {
    shim().nextFamilies2(pd, count, props);
    if (props && *count) props[0].queueFamilyProperties.queueCount = 2;
}

VKAPI_ATTR VkResult VKAPI_CALL CreateDevice(VkPhysicalDevice pd,
                                            const VkDeviceCreateInfo* pCreateInfo,
                                            const VkAllocationCallbacks* pAllocator,
                                            VkDevice* pDevice) {
    auto* link = layerLink<VkLayerDeviceCreateInfo>(pCreateInfo->pNext,
                                                    VK_STRUCTURE_TYPE_LOADER_DEVICE_CREATE_INFO);
    if (!link) return VK_ERROR_INITIALIZATION_FAILED;
    PFN_vkGetInstanceProcAddr gipa = link->u.pLayerInfo->pfnNextGetInstanceProcAddr;
    shim().nextGdpa = link->u.pLayerInfo->pfnNextGetDeviceProcAddr;
    link->u.pLayerInfo = link->u.pLayerInfo->pNext;
    // The driver has one queue: ask it for at most one per family.
    std::vector<VkDeviceQueueCreateInfo> queues(pCreateInfo->pQueueCreateInfos,
                                                pCreateInfo->pQueueCreateInfos +
                                                    pCreateInfo->queueCreateInfoCount);
    for (auto& q : queues) q.queueCount = q.queueCount > 1 ? 1 : q.queueCount;
    VkDeviceCreateInfo info = *pCreateInfo;
    info.pQueueCreateInfos = queues.data();
    auto create = (PFN_vkCreateDevice)gipa(VK_NULL_HANDLE, "vkCreateDevice");
    VkResult r = create(pd, &info, pAllocator, pDevice);
    if (r != VK_SUCCESS) return r;
    shim().nextGetQueue = (PFN_vkGetDeviceQueue)shim().nextGdpa(*pDevice, "vkGetDeviceQueue");
    shim().nextSubmit = (PFN_vkQueueSubmit)shim().nextGdpa(*pDevice, "vkQueueSubmit");
    shim().nextSubmit2 = (PFN_vkQueueSubmit2)shim().nextGdpa(*pDevice, "vkQueueSubmit2");
    shim().nextWaitIdle = (PFN_vkQueueWaitIdle)shim().nextGdpa(*pDevice, "vkQueueWaitIdle");
    return r;
}

VKAPI_ATTR void VKAPI_CALL GetDeviceQueue(VkDevice device, uint32_t family, uint32_t index,
                                          VkQueue* pQueue) {
    VkQueue real;
    shim().nextGetQueue(device, family, 0, &real);
    if (index == 0) {
        *pQueue = real;
        return;
    }
    // A dispatchable handle of our own: its first word is the loader's dispatch table, as the
    // driver's queue's (the loader and the layers above find the device by it).
    auto* fake = new void* [2] { *reinterpret_cast<void**>(real), nullptr };
    std::lock_guard lock(shim().mutex);
    shim().fakes[(VkQueue)fake] = real;
    *pQueue = (VkQueue)fake;
}

VKAPI_ATTR VkResult VKAPI_CALL QueueSubmit(VkQueue q, uint32_t n, const VkSubmitInfo* s,
                                           VkFence f) {
    return shim().nextSubmit(realQueue(q), n, s, f);
}
VKAPI_ATTR VkResult VKAPI_CALL QueueSubmit2(VkQueue q, uint32_t n, const VkSubmitInfo2* s,
                                            VkFence f) {
    return shim().nextSubmit2(realQueue(q), n, s, f);
}
VKAPI_ATTR VkResult VKAPI_CALL QueueWaitIdle(VkQueue q) {
    return shim().nextWaitIdle(realQueue(q));
}

PFN_vkVoidFunction deviceFunction(const char* name) {
    if (!std::strcmp(name, "vkGetDeviceQueue")) return (PFN_vkVoidFunction)GetDeviceQueue;
    if (!std::strcmp(name, "vkQueueSubmit")) return (PFN_vkVoidFunction)QueueSubmit;
    if (!std::strcmp(name, "vkQueueSubmit2")) return (PFN_vkVoidFunction)QueueSubmit2;
    if (!std::strcmp(name, "vkQueueWaitIdle")) return (PFN_vkVoidFunction)QueueWaitIdle;
    return nullptr;
}

VKAPI_ATTR PFN_vkVoidFunction VKAPI_CALL GetDeviceProcAddr(VkDevice device, const char* name) {
    if (auto f = deviceFunction(name)) return f;
    return shim().nextGdpa(device, name);
}

VKAPI_ATTR PFN_vkVoidFunction VKAPI_CALL GetInstanceProcAddr(VkInstance instance,
                                                             const char* name) {
    if (!std::strcmp(name, "vkCreateInstance")) return (PFN_vkVoidFunction)CreateInstance;
    if (!std::strcmp(name, "vkCreateDevice")) return (PFN_vkVoidFunction)CreateDevice;
    if (!std::strcmp(name, "vkGetInstanceProcAddr")) return (PFN_vkVoidFunction)GetInstanceProcAddr;
    if (!std::strcmp(name, "vkGetDeviceProcAddr")) return (PFN_vkVoidFunction)GetDeviceProcAddr;
    if (!std::strcmp(name, "vkGetPhysicalDeviceQueueFamilyProperties"))
        return (PFN_vkVoidFunction)GetPhysicalDeviceQueueFamilyProperties;
    if (!std::strcmp(name, "vkGetPhysicalDeviceQueueFamilyProperties2") ||
        !std::strcmp(name, "vkGetPhysicalDeviceQueueFamilyProperties2KHR"))
        return (PFN_vkVoidFunction)GetPhysicalDeviceQueueFamilyProperties2;
    if (auto f = deviceFunction(name)) return f;
    return shim().nextGipa ? shim().nextGipa(instance, name) : nullptr;
}

}  // namespace

extern "C" __attribute__((visibility("default"))) VKAPI_ATTR VkResult VKAPI_CALL
vkNegotiateLoaderLayerInterfaceVersion(VkNegotiateLayerInterface* v) {
    if (v->loaderLayerInterfaceVersion > 2) v->loaderLayerInterfaceVersion = 2;
    v->pfnGetInstanceProcAddr = GetInstanceProcAddr;
    v->pfnGetDeviceProcAddr = GetDeviceProcAddr;
    v->pfnGetPhysicalDeviceProcAddr = nullptr;
    return VK_SUCCESS;
}
