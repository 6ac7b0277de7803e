// SPDX-License-Identifier: Apache-2.0
// Serving VK_NV_cluster_acceleration_structure where the driver lacks it: the extension in the
// device's list, its feature and properties structs, and the answers to its two entry points.
#include "clastrace/capture/cluster_limits.h"
#include "layer_state.h"

#include <cstring>
#include <map>

namespace clastrace::capture {
namespace {

std::mutex nativeMutex;
std::map<VkPhysicalDevice, bool> nativeSupport;  // cached: the answer does not change

template <typename T>
T* find_in_chain(void* head, VkStructureType type) {
    for (auto* s = (VkBaseOutStructure*)head; s; s = s->pNext)
        if (s->sType == type) return (T*)s;
    return nullptr;
}

// What the layer adds to the driver's device extensions: the cluster extension where it serves
// it, VK_EXT_frame_boundary where the driver lacks it (layer_frame_boundary.cpp).
std::vector<VkExtensionProperties> layer_provided_extensions(InstanceState& instance,
                                                             VkPhysicalDevice physical_device) {
    std::vector<VkExtensionProperties> provided;
    if (should_serve(instance, physical_device))
        provided.push_back({VK_NV_CLUSTER_ACCELERATION_STRUCTURE_EXTENSION_NAME,
                            VK_NV_CLUSTER_ACCELERATION_STRUCTURE_SPEC_VERSION});
    if (!driver_lists_extension(instance, physical_device, VK_EXT_FRAME_BOUNDARY_EXTENSION_NAME))
        provided.push_back(
            {VK_EXT_FRAME_BOUNDARY_EXTENSION_NAME, VK_EXT_FRAME_BOUNDARY_SPEC_VERSION});
    return provided;
}

VkResult copy_extensions(const std::vector<VkExtensionProperties>& all, uint32_t* p_property_count,
                         VkExtensionProperties* p_properties) {
    if (!p_properties) {
        *p_property_count = uint32_t(all.size());
        return VK_SUCCESS;
    }
    const uint32_t written = std::min<uint32_t>(*p_property_count, uint32_t(all.size()));
    std::memcpy(p_properties, all.data(), written * sizeof(VkExtensionProperties));
    *p_property_count = written;
    return written < all.size() ? VK_INCOMPLETE : VK_SUCCESS;
}

VKAPI_ATTR VkResult VKAPI_CALL EnumerateDeviceExtensionProperties(
    VkPhysicalDevice physical_device, const char* p_layer_name, uint32_t* p_property_count,
    VkExtensionProperties* p_properties) {
    InstanceState* instance = find_instance(dispatch_key(physical_device));
    if (!instance) return VK_ERROR_INITIALIZATION_FAILED;
    if (p_layer_name && std::strcmp(p_layer_name, "VK_LAYER_CLASTRACE_capture") == 0)
        return copy_extensions({{VK_NV_CLUSTER_ACCELERATION_STRUCTURE_EXTENSION_NAME,
                                 VK_NV_CLUSTER_ACCELERATION_STRUCTURE_SPEC_VERSION},
                                {VK_EXT_FRAME_BOUNDARY_EXTENSION_NAME,
                                 VK_EXT_FRAME_BOUNDARY_SPEC_VERSION}},
                               p_property_count, p_properties);
    const std::vector<VkExtensionProperties> provided =
        p_layer_name ? std::vector<VkExtensionProperties>{}
                     : layer_provided_extensions(*instance, physical_device);
    if (provided.empty())
        return instance->next.EnumerateDeviceExtensionProperties(physical_device, p_layer_name,
                                                                 p_property_count, p_properties);
    uint32_t driver_count = 0;
    VkResult result = instance->next.EnumerateDeviceExtensionProperties(physical_device, nullptr,
                                                                        &driver_count, nullptr);
    if (result != VK_SUCCESS) return result;
    std::vector<VkExtensionProperties> all(driver_count);
    result = instance->next.EnumerateDeviceExtensionProperties(physical_device, nullptr,
                                                               &driver_count, all.data());
    if (result < 0) return result;
    all.resize(driver_count);
    all.insert(all.end(), provided.begin(), provided.end());
    return copy_extensions(all, p_property_count, p_properties);
}

// The driver never sees the provided features' structs: they are unlinked for its call and
// filled after.
void features_common(VkPhysicalDevice physical_device, VkPhysicalDeviceFeatures2* p_features,
                     bool khr) {
    InstanceState* instance = find_instance(dispatch_key(physical_device));
    if (!instance) return;
    auto next = khr ? instance->next.GetPhysicalDeviceFeatures2KHR
                    : instance->next.GetPhysicalDeviceFeatures2;
    auto* cluster =
        should_serve(*instance, physical_device)
            ? find_in_chain<VkPhysicalDeviceClusterAccelerationStructureFeaturesNV>(
                  p_features,
                  VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_FEATURES_NV)
            : nullptr;
    auto* boundary = find_in_chain<VkPhysicalDeviceFrameBoundaryFeaturesEXT>(
        p_features, VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FRAME_BOUNDARY_FEATURES_EXT);
    if (boundary &&
        driver_lists_extension(*instance, physical_device, VK_EXT_FRAME_BOUNDARY_EXTENSION_NAME))
        boundary = nullptr;
    {
        ChainUnlink hide_cluster(
            cluster ? p_features : nullptr,
            VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_FEATURES_NV);
        ChainUnlink hide_boundary(boundary ? p_features : nullptr,
                                  VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FRAME_BOUNDARY_FEATURES_EXT);
        next(physical_device, p_features);
    }
    if (cluster) cluster->clusterAccelerationStructure = VK_TRUE;
    if (boundary) boundary->frameBoundary = VK_TRUE;
}

VKAPI_ATTR void VKAPI_CALL GetPhysicalDeviceFeatures2(VkPhysicalDevice pd,
                                                      VkPhysicalDeviceFeatures2* f) {
    features_common(pd, f, false);
}
VKAPI_ATTR void VKAPI_CALL GetPhysicalDeviceFeatures2KHR(VkPhysicalDevice pd,
                                                         VkPhysicalDeviceFeatures2* f) {
    features_common(pd, f, true);
}

void properties_common(VkPhysicalDevice physical_device, VkPhysicalDeviceProperties2* p_properties,
                       bool khr) {
    InstanceState* instance = find_instance(dispatch_key(physical_device));
    if (!instance) return;
    auto next = khr ? instance->next.GetPhysicalDeviceProperties2KHR
                    : instance->next.GetPhysicalDeviceProperties2;
    if (!should_serve(*instance, physical_device)) {
        next(physical_device, p_properties);
        return;
    }
    auto* served = find_in_chain<VkPhysicalDeviceClusterAccelerationStructurePropertiesNV>(
        p_properties,
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_PROPERTIES_NV);
    if (!served) {
        next(physical_device, p_properties);
        return;
    }
    VkBaseOutStructure* previous = (VkBaseOutStructure*)p_properties;
    while (previous->pNext != (VkBaseOutStructure*)served) previous = previous->pNext;
    previous->pNext = (VkBaseOutStructure*)served->pNext;
    next(physical_device, p_properties);
    previous->pNext = (VkBaseOutStructure*)served;
    void* chain = served->pNext;
    *served = served_cluster_properties();
    served->pNext = chain;
}

VKAPI_ATTR void VKAPI_CALL GetPhysicalDeviceProperties2(VkPhysicalDevice pd,
                                                        VkPhysicalDeviceProperties2* p) {
    properties_common(pd, p, false);
}
VKAPI_ATTR void VKAPI_CALL GetPhysicalDeviceProperties2KHR(VkPhysicalDevice pd,
                                                           VkPhysicalDeviceProperties2* p) {
    properties_common(pd, p, true);
}

}  // namespace

bool driver_lists_extension(InstanceState& instance, VkPhysicalDevice physical_device,
                            const char* name) {
    uint32_t count = 0;
    if (instance.next.EnumerateDeviceExtensionProperties(physical_device, nullptr, &count,
                                                         nullptr) != VK_SUCCESS)
        return false;
    std::vector<VkExtensionProperties> all(count);
    if (instance.next.EnumerateDeviceExtensionProperties(physical_device, nullptr, &count,
                                                         all.data()) < 0)
        return false;
    for (uint32_t i = 0; i < count; ++i)
        if (std::strcmp(all[i].extensionName, name) == 0) return true;
    return false;
}

bool driver_has_cluster_extension(InstanceState& instance, VkPhysicalDevice physical_device) {
    {
        std::lock_guard lock(nativeMutex);
        auto it = nativeSupport.find(physical_device);
        if (it != nativeSupport.end()) return it->second;
    }
    const bool found = driver_lists_extension(instance, physical_device,
                                              VK_NV_CLUSTER_ACCELERATION_STRUCTURE_EXTENSION_NAME);
    std::lock_guard lock(nativeMutex);
    nativeSupport[physical_device] = found;
    return found;
}

bool should_serve(InstanceState& instance, VkPhysicalDevice physical_device) {
    switch (layer_config().serve) {
    case ServeMode::kOff: return false;
    case ServeMode::kOn: return true;
    case ServeMode::kAuto: return !driver_has_cluster_extension(instance, physical_device);
    }
    return false;
}

VkPhysicalDeviceClusterAccelerationStructurePropertiesNV cluster_properties_for(
    InstanceState& instance, VkPhysicalDevice physical_device, bool serving) {
    VkPhysicalDeviceClusterAccelerationStructurePropertiesNV cluster{};
    cluster.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_PROPERTIES_NV;
    if (serving) return served_cluster_properties();
    if (!driver_has_cluster_extension(instance, physical_device) ||
        !instance.next.GetPhysicalDeviceProperties2)
        return cluster;
    VkPhysicalDeviceProperties2 properties{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2,
                                           &cluster,
                                           {}};
    instance.next.GetPhysicalDeviceProperties2(physical_device, &properties);
    cluster.pNext = nullptr;
    return cluster;
}

PFN_vkVoidFunction serving_instance_hook(const char* name) {
    static const std::map<std::string, PFN_vkVoidFunction, std::less<>> kHooks = {
        {"vkEnumerateDeviceExtensionProperties",
         (PFN_vkVoidFunction)EnumerateDeviceExtensionProperties},
        {"vkGetPhysicalDeviceFeatures2", (PFN_vkVoidFunction)GetPhysicalDeviceFeatures2},
        {"vkGetPhysicalDeviceFeatures2KHR", (PFN_vkVoidFunction)GetPhysicalDeviceFeatures2KHR},
        {"vkGetPhysicalDeviceProperties2", (PFN_vkVoidFunction)GetPhysicalDeviceProperties2},
        {"vkGetPhysicalDeviceProperties2KHR", (PFN_vkVoidFunction)GetPhysicalDeviceProperties2KHR},
    };
    auto it = kHooks.find(name);
    return it == kHooks.end() ? nullptr : it->second;
}

}  // namespace clastrace::capture
