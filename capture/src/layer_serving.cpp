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
T* findInChain(void* head, VkStructureType type) {
  for (auto* s = (VkBaseOutStructure*)head; s; s = s->pNext)
    if (s->sType == type) return (T*)s;
  return nullptr;
}

VKAPI_ATTR VkResult VKAPI_CALL EnumerateDeviceExtensionProperties(VkPhysicalDevice physicalDevice,
                                                                  const char* pLayerName, uint32_t* pPropertyCount,
                                                                  VkExtensionProperties* pProperties) {
  InstanceState* instance = findInstance(dispatchKey(physicalDevice));
  if (!instance) return VK_ERROR_INITIALIZATION_FAILED;
  const VkExtensionProperties served{VK_NV_CLUSTER_ACCELERATION_STRUCTURE_EXTENSION_NAME,
                                     VK_NV_CLUSTER_ACCELERATION_STRUCTURE_SPEC_VERSION};
  if (pLayerName && std::strcmp(pLayerName, "VK_LAYER_CLASTRACE_capture") == 0) {
    if (!pProperties) {
      *pPropertyCount = 1;
      return VK_SUCCESS;
    }
    if (*pPropertyCount < 1) return VK_INCOMPLETE;
    pProperties[0] = served;
    *pPropertyCount = 1;
    return VK_SUCCESS;
  }
  if (pLayerName || !shouldServe(*instance, physicalDevice))
    return instance->next.EnumerateDeviceExtensionProperties(physicalDevice, pLayerName, pPropertyCount, pProperties);

  uint32_t driverCount = 0;
  VkResult result = instance->next.EnumerateDeviceExtensionProperties(physicalDevice, nullptr, &driverCount, nullptr);
  if (result != VK_SUCCESS) return result;
  if (!pProperties) {
    *pPropertyCount = driverCount + 1;
    return VK_SUCCESS;
  }
  std::vector<VkExtensionProperties> all(driverCount);
  result = instance->next.EnumerateDeviceExtensionProperties(physicalDevice, nullptr, &driverCount, all.data());
  if (result < 0) return result;
  all.resize(driverCount);
  all.push_back(served);
  const uint32_t written = std::min<uint32_t>(*pPropertyCount, uint32_t(all.size()));
  std::memcpy(pProperties, all.data(), written * sizeof(VkExtensionProperties));
  *pPropertyCount = written;
  return written < all.size() ? VK_INCOMPLETE : VK_SUCCESS;
}

// The driver never sees the served structs: they are unlinked for its call and filled after.
void featuresCommon(VkPhysicalDevice physicalDevice, VkPhysicalDeviceFeatures2* pFeatures, bool khr) {
  InstanceState* instance = findInstance(dispatchKey(physicalDevice));
  if (!instance) return;
  auto next = khr ? instance->next.GetPhysicalDeviceFeatures2KHR : instance->next.GetPhysicalDeviceFeatures2;
  if (!shouldServe(*instance, physicalDevice)) {
    next(physicalDevice, pFeatures);
    return;
  }
  auto* served = findInChain<VkPhysicalDeviceClusterAccelerationStructureFeaturesNV>(
      pFeatures, VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_FEATURES_NV);
  if (!served) {
    next(physicalDevice, pFeatures);
    return;
  }
  VkBaseOutStructure* previous = (VkBaseOutStructure*)pFeatures;
  while (previous->pNext != (VkBaseOutStructure*)served) previous = previous->pNext;
  previous->pNext = (VkBaseOutStructure*)served->pNext;
  next(physicalDevice, pFeatures);
  previous->pNext = (VkBaseOutStructure*)served;
  served->clusterAccelerationStructure = VK_TRUE;
}

VKAPI_ATTR void VKAPI_CALL GetPhysicalDeviceFeatures2(VkPhysicalDevice pd, VkPhysicalDeviceFeatures2* f) {
  featuresCommon(pd, f, false);
}
VKAPI_ATTR void VKAPI_CALL GetPhysicalDeviceFeatures2KHR(VkPhysicalDevice pd, VkPhysicalDeviceFeatures2* f) {
  featuresCommon(pd, f, true);
}

void propertiesCommon(VkPhysicalDevice physicalDevice, VkPhysicalDeviceProperties2* pProperties, bool khr) {
  InstanceState* instance = findInstance(dispatchKey(physicalDevice));
  if (!instance) return;
  auto next = khr ? instance->next.GetPhysicalDeviceProperties2KHR : instance->next.GetPhysicalDeviceProperties2;
  if (!shouldServe(*instance, physicalDevice)) {
    next(physicalDevice, pProperties);
    return;
  }
  auto* served = findInChain<VkPhysicalDeviceClusterAccelerationStructurePropertiesNV>(
      pProperties, VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_PROPERTIES_NV);
  if (!served) {
    next(physicalDevice, pProperties);
    return;
  }
  VkBaseOutStructure* previous = (VkBaseOutStructure*)pProperties;
  while (previous->pNext != (VkBaseOutStructure*)served) previous = previous->pNext;
  previous->pNext = (VkBaseOutStructure*)served->pNext;
  next(physicalDevice, pProperties);
  previous->pNext = (VkBaseOutStructure*)served;
  void* chain = served->pNext;
  *served = servedClusterProperties();
  served->pNext = chain;
}

VKAPI_ATTR void VKAPI_CALL GetPhysicalDeviceProperties2(VkPhysicalDevice pd, VkPhysicalDeviceProperties2* p) {
  propertiesCommon(pd, p, false);
}
VKAPI_ATTR void VKAPI_CALL GetPhysicalDeviceProperties2KHR(VkPhysicalDevice pd, VkPhysicalDeviceProperties2* p) {
  propertiesCommon(pd, p, true);
}

}  // namespace

bool driverHasClusterExtension(InstanceState& instance, VkPhysicalDevice physicalDevice) {
  {
    std::lock_guard lock(nativeMutex);
    auto it = nativeSupport.find(physicalDevice);
    if (it != nativeSupport.end()) return it->second;
  }
  uint32_t count = 0;
  bool found = false;
  if (instance.next.EnumerateDeviceExtensionProperties(physicalDevice, nullptr, &count, nullptr) == VK_SUCCESS) {
    std::vector<VkExtensionProperties> all(count);
    if (instance.next.EnumerateDeviceExtensionProperties(physicalDevice, nullptr, &count, all.data()) >= 0)
      for (uint32_t i = 0; i < count; ++i)
        found |= std::strcmp(all[i].extensionName, VK_NV_CLUSTER_ACCELERATION_STRUCTURE_EXTENSION_NAME) == 0;
  }
  std::lock_guard lock(nativeMutex);
  nativeSupport[physicalDevice] = found;
  return found;
}

bool shouldServe(InstanceState& instance, VkPhysicalDevice physicalDevice) {
  switch (layerConfig().serve) {
    case ServeMode::Off: return false;
    case ServeMode::On: return true;
    case ServeMode::Auto: return !driverHasClusterExtension(instance, physicalDevice);
  }
  return false;
}

VkPhysicalDeviceClusterAccelerationStructurePropertiesNV clusterPropertiesFor(InstanceState& instance,
                                                                              VkPhysicalDevice physicalDevice,
                                                                              bool serving) {
  VkPhysicalDeviceClusterAccelerationStructurePropertiesNV cluster{};
  cluster.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_PROPERTIES_NV;
  if (serving) return servedClusterProperties();
  if (!driverHasClusterExtension(instance, physicalDevice) || !instance.next.GetPhysicalDeviceProperties2) return cluster;
  VkPhysicalDeviceProperties2 properties{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2, &cluster, {}};
  instance.next.GetPhysicalDeviceProperties2(physicalDevice, &properties);
  cluster.pNext = nullptr;
  return cluster;
}

PFN_vkVoidFunction servingInstanceHook(const char* name) {
  static const std::map<std::string, PFN_vkVoidFunction, std::less<>> hooks = {
      {"vkEnumerateDeviceExtensionProperties", (PFN_vkVoidFunction)EnumerateDeviceExtensionProperties},
      {"vkGetPhysicalDeviceFeatures2", (PFN_vkVoidFunction)GetPhysicalDeviceFeatures2},
      {"vkGetPhysicalDeviceFeatures2KHR", (PFN_vkVoidFunction)GetPhysicalDeviceFeatures2KHR},
      {"vkGetPhysicalDeviceProperties2", (PFN_vkVoidFunction)GetPhysicalDeviceProperties2},
      {"vkGetPhysicalDeviceProperties2KHR", (PFN_vkVoidFunction)GetPhysicalDeviceProperties2KHR},
  };
  auto it = hooks.find(name);
  return it == hooks.end() ? nullptr : it->second;
}

}  // namespace clastrace::capture
