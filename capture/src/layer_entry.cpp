// Loader-facing part: interface negotiation, instance and device creation with the next
// layer's entry points, the registries, and the proc-address interception.
#include "layer_state.h"

#include "clastrace/capture/background_cpus.h"
#include "clastrace/capture/capture_cost.h"
#include "command_buffer_log.h"
#include "pause_worker.h"

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <string>

namespace clastrace::capture {
namespace {

constexpr const char* kLayerName = "VK_LAYER_CLASTRACE_capture";

std::shared_mutex registryMutex;
std::unordered_map<DispatchKey, std::unique_ptr<InstanceState>>& instances() {
  static std::unordered_map<DispatchKey, std::unique_ptr<InstanceState>> map;
  return map;
}
std::unordered_map<DispatchKey, std::unique_ptr<DeviceState>>& devices() {
  static std::unordered_map<DispatchKey, std::unique_ptr<DeviceState>> map;
  return map;
}

template <typename CreateInfo, typename LinkInfo>
LinkInfo* findLayerLink(const CreateInfo* createInfo, VkStructureType type) {
  auto* link = (LinkInfo*)createInfo->pNext;
  while (link && !(link->sType == type && link->function == VK_LAYER_LINK_INFO)) link = (LinkInfo*)link->pNext;
  return link;
}

VKAPI_ATTR VkResult VKAPI_CALL CreateInstance(const VkInstanceCreateInfo* pCreateInfo,
                                              const VkAllocationCallbacks* pAllocator, VkInstance* pInstance) {
  auto* link = findLayerLink<VkInstanceCreateInfo, VkLayerInstanceCreateInfo>(
      pCreateInfo, VK_STRUCTURE_TYPE_LOADER_INSTANCE_CREATE_INFO);
  if (!link || !link->u.pLayerInfo) return VK_ERROR_INITIALIZATION_FAILED;
  PFN_vkGetInstanceProcAddr nextGipa = link->u.pLayerInfo->pfnNextGetInstanceProcAddr;
  auto nextCreate = (PFN_vkCreateInstance)nextGipa(VK_NULL_HANDLE, "vkCreateInstance");
  if (!nextCreate) return VK_ERROR_INITIALIZATION_FAILED;
  link->u.pLayerInfo = link->u.pLayerInfo->pNext;  // the next layer finds its own link
  VkResult result = nextCreate(pCreateInfo, pAllocator, pInstance);
  if (result != VK_SUCCESS) return result;

  layerConfig();  // parse (and report) the settings at a predictable moment
  auto state = std::make_unique<InstanceState>();
  state->instance = *pInstance;
  if (const VkApplicationInfo* app = pCreateInfo->pApplicationInfo) {
    if (app->pApplicationName) state->applicationName = app->pApplicationName;
    if (app->pEngineName) state->engineName = app->pEngineName;
  }
  state->apiVersion = pCreateInfo->pApplicationInfo && pCreateInfo->pApplicationInfo->apiVersion
                          ? pCreateInfo->pApplicationInfo->apiVersion
                          : VK_API_VERSION_1_0;
#define CLASTRACE_LOAD(name) state->next.name = (PFN_vk##name)nextGipa(*pInstance, "vk" #name);
  CLASTRACE_INSTANCE_FUNCTIONS(CLASTRACE_LOAD)
#undef CLASTRACE_LOAD
  state->next.GetInstanceProcAddr = nextGipa;
  registerInstance(dispatchKey(*pInstance), std::move(state));
  return VK_SUCCESS;
}

VKAPI_ATTR void VKAPI_CALL DestroyInstance(VkInstance instance, const VkAllocationCallbacks* pAllocator) {
  auto state = unregisterInstance(dispatchKey(instance));
  if (state && state->next.DestroyInstance) state->next.DestroyInstance(instance, pAllocator);
}

// Removes `target` from a const pNext chain for the duration of one call, then restores it.
struct ChainUnlink {
  VkBaseOutStructure* previous = nullptr;
  VkBaseOutStructure* removed = nullptr;
  ChainUnlink(const void* head, VkStructureType type) {
    auto* prev = (VkBaseOutStructure*)head;
    while (prev && prev->pNext) {
      if (prev->pNext->sType == type) {
        previous = prev;
        removed = prev->pNext;
        prev->pNext = removed->pNext;
        return;
      }
      prev = prev->pNext;
    }
  }
  ~ChainUnlink() {
    if (previous) previous->pNext = removed;
  }
};

// Driver name, UUIDs and NV ray-tracing limits (Vulkan 1.2 devices): what tells a serialized
// acceleration structure of this driver from another's, and what the ray check builds on.
void fillDriverIdentity(InstanceState& instance, VkPhysicalDevice physicalDevice, uint32_t apiVersion,
                        DeviceState& state, DeviceRecord& record) {
  if (!instance.next.GetPhysicalDeviceProperties2 || apiVersion < VK_API_VERSION_1_2) return;
  VkPhysicalDeviceRayTracingPropertiesNV rayTracing{};
  rayTracing.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_RAY_TRACING_PROPERTIES_NV;
  VkPhysicalDeviceDriverProperties driver{};
  driver.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_DRIVER_PROPERTIES;
  driver.pNext = state.nvRayTracingEnabled ? &rayTracing : nullptr;
  VkPhysicalDeviceIDProperties ids{};
  ids.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_ID_PROPERTIES;
  ids.pNext = &driver;
  VkPhysicalDeviceProperties2 properties{};
  properties.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2;
  properties.pNext = &ids;
  instance.next.GetPhysicalDeviceProperties2(physicalDevice, &properties);
  record.driverId = uint32_t(driver.driverID);
  record.driverName = driver.driverName;
  record.driverInfo = driver.driverInfo;
  record.driverUuid.assign(ids.driverUUID, ids.driverUUID + VK_UUID_SIZE);
  record.deviceUuid.assign(ids.deviceUUID, ids.deviceUUID + VK_UUID_SIZE);
  if (state.nvRayTracingEnabled) {
    rayTracing.pNext = nullptr;
    state.rayTracingPropertiesNV = rayTracing;
    record.hasRayTracingPropertiesNV = true;
    record.rayTracingPropertiesNV = rayTracing;
  }
}

VKAPI_ATTR VkResult VKAPI_CALL CreateDevice(VkPhysicalDevice physicalDevice, const VkDeviceCreateInfo* pCreateInfo,
                                            const VkAllocationCallbacks* pAllocator, VkDevice* pDevice) {
  InstanceState* instance = findInstance(dispatchKey(physicalDevice));
  auto* link = findLayerLink<VkDeviceCreateInfo, VkLayerDeviceCreateInfo>(pCreateInfo,
                                                                          VK_STRUCTURE_TYPE_LOADER_DEVICE_CREATE_INFO);
  if (!instance || !link || !link->u.pLayerInfo) return VK_ERROR_INITIALIZATION_FAILED;
  PFN_vkGetInstanceProcAddr nextGipa = link->u.pLayerInfo->pfnNextGetInstanceProcAddr;
  PFN_vkGetDeviceProcAddr nextGdpa = link->u.pLayerInfo->pfnNextGetDeviceProcAddr;
  auto nextCreate = (PFN_vkCreateDevice)nextGipa(instance->instance, "vkCreateDevice");
  if (!nextCreate) return VK_ERROR_INITIALIZATION_FAILED;
  link->u.pLayerInfo = link->u.pLayerInfo->pNext;

  const bool serving = shouldServe(*instance, physicalDevice);
  bool clusterExtensionRequested = false;
  std::vector<const char*> extensions;
  for (uint32_t i = 0; i < pCreateInfo->enabledExtensionCount; ++i) {
    if (std::strcmp(pCreateInfo->ppEnabledExtensionNames[i], VK_NV_CLUSTER_ACCELERATION_STRUCTURE_EXTENSION_NAME) == 0) {
      clusterExtensionRequested = true;
      if (serving) continue;  // the driver does not know it; the layer provides it
    }
    extensions.push_back(pCreateInfo->ppEnabledExtensionNames[i]);
  }
  bool clusterFeatureRequested = false;
  for (auto* s = (const VkBaseInStructure*)pCreateInfo->pNext; s; s = s->pNext)
    if (s->sType == VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_FEATURES_NV)
      clusterFeatureRequested =
          ((const VkPhysicalDeviceClusterAccelerationStructureFeaturesNV*)s)->clusterAccelerationStructure == VK_TRUE;

  VkDeviceCreateInfo driverInfo = *pCreateInfo;
  driverInfo.enabledExtensionCount = uint32_t(extensions.size());
  driverInfo.ppEnabledExtensionNames = extensions.data();
  VkResult result;
  {
    // A served feature struct is unknown to the driver: hide it from the driver's view only.
    ChainUnlink hideFeatures(serving ? &driverInfo : nullptr,
                             VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_FEATURES_NV);
    result = nextCreate(physicalDevice, &driverInfo, pAllocator, pDevice);
  }
  if (result != VK_SUCCESS) return result;

  auto state = std::make_unique<DeviceState>();
  state->device = *pDevice;
  state->physicalDevice = physicalDevice;
  state->instance = instance;
#define CLASTRACE_LOAD(name) state->next.name = (PFN_vk##name)nextGdpa(*pDevice, "vk" #name);
  CLASTRACE_DEVICE_FUNCTIONS(CLASTRACE_LOAD)
#undef CLASTRACE_LOAD
  state->next.GetDeviceProcAddr = nextGdpa;
  if (serving) {  // whatever the driver answers for these names, the layer owns them
    state->next.CmdBuildClusterAccelerationStructureIndirectNV = nullptr;
    state->next.GetClusterAccelerationStructureBuildSizesNV = nullptr;
  }
  state->serving = serving;
  state->clusterEnabled = clusterExtensionRequested;

  VkPhysicalDeviceProperties properties{};
  instance->next.GetPhysicalDeviceProperties(physicalDevice, &properties);
  instance->next.GetPhysicalDeviceMemoryProperties(physicalDevice, &state->memoryProperties);
  state->nonCoherentAtomSize = properties.limits.nonCoherentAtomSize ? properties.limits.nonCoherentAtomSize : 1;
  state->clusterProperties = clusterPropertiesFor(*instance, physicalDevice, serving);
  for (uint32_t i = 0; i < pCreateInfo->enabledExtensionCount; ++i)
    if (std::strcmp(pCreateInfo->ppEnabledExtensionNames[i], VK_NV_RAY_TRACING_EXTENSION_NAME) == 0)
      state->nvRayTracingEnabled = true;

  const LayerConfig& config = layerConfig();
  if (config.capture) state->sink = processCaptureSink();
  state->capturing = state->sink != nullptr;
  if (state->capturing && config.timestamps && pCreateInfo->queueCreateInfoCount) {
    uint32_t familyCount = 0;
    instance->next.GetPhysicalDeviceQueueFamilyProperties(physicalDevice, &familyCount, nullptr);
    std::vector<VkQueueFamilyProperties> families(familyCount);
    instance->next.GetPhysicalDeviceQueueFamilyProperties(physicalDevice, &familyCount, families.data());
    uint32_t validBits = 64;
    for (uint32_t i = 0; i < pCreateInfo->queueCreateInfoCount; ++i) {
      const uint32_t family = pCreateInfo->pQueueCreateInfos[i].queueFamilyIndex;
      validBits = std::min(validBits, family < familyCount ? families[family].timestampValidBits : 0u);
    }
    state->timestamps = validBits != 0 && state->next.CreateQueryPool && state->next.CmdWriteTimestamp &&
                        state->next.CmdResetQueryPool && state->next.GetQueryPoolResults;
    state->timestampMask = validBits >= 64 ? ~0ull : (1ull << validBits) - 1;
  }
  if (state->capturing || serving) state->pauses = std::make_unique<PauseWorker>(*state);
  logMessage(LogLevel::Info, "device %s: serving %s, capture %s, timestamps %s", properties.deviceName,
             serving ? "on" : "off", state->capturing ? "on" : "off", state->timestamps ? "on" : "off");

  if (state->sink) {
    DeviceRecord record;
    record.device = handleId(*pDevice);
    record.deviceName = properties.deviceName;
    record.applicationName = instance->applicationName;
    record.engineName = instance->engineName;
    record.apiVersion = properties.apiVersion;
    record.vendorId = properties.vendorID;
    record.deviceId = properties.deviceID;
    record.driverVersion = properties.driverVersion;
    record.deviceType = properties.deviceType;
    record.pipelineCacheUuid.assign(properties.pipelineCacheUUID, properties.pipelineCacheUUID + VK_UUID_SIZE);
    record.timestampPeriod = properties.limits.timestampPeriod;
    record.memoryHeaps.assign(state->memoryProperties.memoryHeaps,
                              state->memoryProperties.memoryHeaps + state->memoryProperties.memoryHeapCount);
    for (uint32_t i = 0; i < pCreateInfo->enabledExtensionCount; ++i)
      record.enabledExtensions.push_back(pCreateInfo->ppEnabledExtensionNames[i]);
    // Serving matters to the trace only when the application uses the served extension: an NV
    // ray-tracing program on a driver without it is a plain native capture.
    record.servedByLayer = serving && clusterExtensionRequested;
    record.clusterProperties = state->clusterProperties;
    record.clusterFeatureEnabled = clusterExtensionRequested && clusterFeatureRequested;
    record.memoryTypes.assign(state->memoryProperties.memoryTypes,
                              state->memoryProperties.memoryTypes + state->memoryProperties.memoryTypeCount);
    fillDriverIdentity(*instance, physicalDevice, properties.apiVersion, *state, record);
    state->sink->deviceCreated(record);
  }
  registerDevice(dispatchKey(*pDevice), std::move(state));
  return VK_SUCCESS;
}

VKAPI_ATTR void VKAPI_CALL DestroyDevice(VkDevice device, const VkAllocationCallbacks* pAllocator) {
  auto state = unregisterDevice(dispatchKey(device));
  if (!state) return;
  state->pauses.reset();  // stops the worker before the device's events go away
  if (state->sink) {
    state->sink->deviceDestroyed(handleId(device));
    state->sink->flush();
  }
  if (layerConfig().stats) {  // after the flush, so the trace's numbers are final
    for (const std::string& line : costReport(state->sink ? state->sink->costLines() : std::vector<std::string>{}))
      std::fprintf(stderr, "clastrace: %s\n", line.c_str());
  }
  for (auto& [commandBuffer, log] : state->commandBuffers) releaseCommandBufferLog(*state, *log);
  PFN_vkDestroyDevice destroy = state->next.DestroyDevice;
  state.reset();  // frees the layer's events and mappings while the device still exists
  destroy(device, pAllocator);
}

VKAPI_ATTR PFN_vkVoidFunction VKAPI_CALL GetDeviceProcAddr(VkDevice device, const char* pName);

VKAPI_ATTR PFN_vkVoidFunction VKAPI_CALL GetInstanceProcAddr(VkInstance instance, const char* pName) {
  if (std::strcmp(pName, "vkGetInstanceProcAddr") == 0) return (PFN_vkVoidFunction)GetInstanceProcAddr;
  if (std::strcmp(pName, "vkCreateInstance") == 0) return (PFN_vkVoidFunction)CreateInstance;
  if (std::strcmp(pName, "vkDestroyInstance") == 0) return (PFN_vkVoidFunction)DestroyInstance;
  if (std::strcmp(pName, "vkCreateDevice") == 0) return (PFN_vkVoidFunction)CreateDevice;
  if (std::strcmp(pName, "vkGetDeviceProcAddr") == 0) return (PFN_vkVoidFunction)GetDeviceProcAddr;
  if (std::strcmp(pName, "vkDestroyDevice") == 0) return (PFN_vkVoidFunction)DestroyDevice;
  if (!instance) return nullptr;
  InstanceState* state = findInstance(dispatchKey(instance));
  if (!state) return nullptr;
  PFN_vkVoidFunction next = state->next.GetInstanceProcAddr(instance, pName);
  if (PFN_vkVoidFunction hook = servingInstanceHook(pName)) return next ? hook : nullptr;
  // Device functions asked through the instance: ours only where the driver chain has them,
  // except the served extension's, which the layer provides on its own.
  if (PFN_vkVoidFunction hook = interceptDeviceFunction(pName, nullptr)) return next ? hook : next;
  if (std::strcmp(pName, "vkCmdBuildClusterAccelerationStructureIndirectNV") == 0 ||
      std::strcmp(pName, "vkGetClusterAccelerationStructureBuildSizesNV") == 0)
    return layerConfig().serve != ServeMode::Off ? clusterHook(pName) : next;
  return next;
}

VKAPI_ATTR PFN_vkVoidFunction VKAPI_CALL GetDeviceProcAddr(VkDevice device, const char* pName) {
  if (std::strcmp(pName, "vkGetDeviceProcAddr") == 0) return (PFN_vkVoidFunction)GetDeviceProcAddr;
  if (std::strcmp(pName, "vkDestroyDevice") == 0) return (PFN_vkVoidFunction)DestroyDevice;
  if (!device) return nullptr;
  DeviceState* state = findDevice(dispatchKey(device));
  if (!state) return nullptr;
  if (PFN_vkVoidFunction hook = interceptDeviceFunction(pName, state)) return hook;
  return state->next.GetDeviceProcAddr(device, pName);
}

std::mutex sinkMutex;
// Kept for the whole process: a trace is finished (index and trailer written) when the
// sink is destroyed, at exit or when the loader unloads the layer, so a second device of
// the same process appends to the same trace instead of truncating it.
std::shared_ptr<CaptureSink> sharedSink;
bool sinkFailed = false;

}  // namespace

DeviceState::~DeviceState() = default;

uint64_t nextSubmissionIndex() {
  static std::atomic<uint64_t> counter{0};
  return counter++;
}

InstanceState* findInstance(DispatchKey key) {
  std::shared_lock lock(registryMutex);
  auto it = instances().find(key);
  return it == instances().end() ? nullptr : it->second.get();
}
DeviceState* findDevice(DispatchKey key) {
  std::shared_lock lock(registryMutex);
  auto it = devices().find(key);
  return it == devices().end() ? nullptr : it->second.get();
}
void registerInstance(DispatchKey key, std::unique_ptr<InstanceState> state) {
  std::unique_lock lock(registryMutex);
  instances()[key] = std::move(state);
}
std::unique_ptr<InstanceState> unregisterInstance(DispatchKey key) {
  std::unique_lock lock(registryMutex);
  auto it = instances().find(key);
  if (it == instances().end()) return nullptr;
  auto state = std::move(it->second);
  instances().erase(it);
  return state;
}
void registerDevice(DispatchKey key, std::unique_ptr<DeviceState> state) {
  std::unique_lock lock(registryMutex);
  devices()[key] = std::move(state);
}
std::unique_ptr<DeviceState> unregisterDevice(DispatchKey key) {
  std::unique_lock lock(registryMutex);
  auto it = devices().find(key);
  if (it == devices().end()) return nullptr;
  auto state = std::move(it->second);
  devices().erase(it);
  return state;
}

void logMessage(LogLevel level, const char* format, ...) {
  if (int(level) > int(layerConfig().log)) return;
  char text[1024];
  va_list args;
  va_start(args, format);
  std::vsnprintf(text, sizeof text, format, args);
  va_end(args);
  std::fprintf(stderr, "clastrace: %s\n", text);
}

std::shared_ptr<CaptureSink> processCaptureSink() {
  std::lock_guard lock(sinkMutex);
  if (sharedSink) return sharedSink;
  if (sinkFailed) return nullptr;
  const LayerConfig& config = layerConfig();
  std::string error;
  std::shared_ptr<CaptureSink> sink;
  if (!config.debugJsonPath.empty()) {
    sink = makeJsonCaptureSink(config.debugJsonPath, error);
  } else if (!config.outputPath.empty()) {
    // Decided on the application's thread creating the device: its affinity is the application's.
    BackgroundPlacement placement;
    placement.applicationCpus = callingThreadCpus();
    placement.cpus =
        backgroundCpusFor(config.backgroundCpus, onlineCpus(), placement.applicationCpus, reservedCpus());
    logMessage(LogLevel::Info, "background threads: CPUs %s (the application's: %s)",
               placement.cpus.empty() ? "of the application" : formatCpuList(placement.cpus).c_str(),
               formatCpuList(placement.applicationCpus).c_str());
    sink = makeTraceCaptureSink(config.outputPath, config.zstdLevel, error, config.flushMilliseconds,
                                std::move(placement), config.outputFd);
  } else {
    // Serving alone is a normal use (CI drivers): no output named means no capture, quietly.
    sinkFailed = true;
    logMessage(LogLevel::Info, "capture off: CLASTRACE_OUTPUT is not set");
    return nullptr;
  }
  if (!sink) {
    sinkFailed = true;  // one message per process, then the application runs without capture
    std::fprintf(stderr, "clastrace: capture disabled: %s; the application continues without capture\n",
                 error.c_str());
    return nullptr;
  }
  sharedSink = sink;
  return sink;
}

PFN_vkVoidFunction interceptDeviceFunction(const char* name, DeviceState* device) {
  if (std::strcmp(name, "vkCmdBuildClusterAccelerationStructureIndirectNV") == 0 ||
      std::strcmp(name, "vkGetClusterAccelerationStructureBuildSizesNV") == 0) {
    if (!device) return nullptr;  // GetInstanceProcAddr decides these itself
    const bool native = std::strcmp(name, "vkGetClusterAccelerationStructureBuildSizesNV") == 0
                            ? device->next.GetClusterAccelerationStructureBuildSizesNV != nullptr
                            : device->next.CmdBuildClusterAccelerationStructureIndirectNV != nullptr;
    return device->serving || native ? clusterHook(name) : nullptr;
  }
  PFN_vkVoidFunction hook = resourceHook(name);
  if (!hook) hook = accelerationStructureHook(name);
  if (!hook) hook = commandHook(name);
  if (!hook) hook = submitHook(name);
  if (!hook) hook = hostSyncHook(name);
  if (!hook) hook = presentHook(name);
  if (!hook || !device) return hook;
  // Forward only what the driver chain has: the hook would call a null pointer otherwise.
  return device->next.GetDeviceProcAddr(device->device, name) ? hook : nullptr;
}

}  // namespace clastrace::capture

using namespace clastrace::capture;

extern "C" __attribute__((visibility("default"))) VKAPI_ATTR VkResult VKAPI_CALL
vkNegotiateLoaderLayerInterfaceVersion(VkNegotiateLayerInterface* pVersionStruct) {
  if (!pVersionStruct || pVersionStruct->sType != LAYER_NEGOTIATE_INTERFACE_STRUCT)
    return VK_ERROR_INITIALIZATION_FAILED;
  // Version 2 is the first with the negotiated proc-address functions; nothing newer is needed.
  if (pVersionStruct->loaderLayerInterfaceVersion < 2) return VK_ERROR_INITIALIZATION_FAILED;
  pVersionStruct->loaderLayerInterfaceVersion = 2;
  pVersionStruct->pfnGetInstanceProcAddr = GetInstanceProcAddr;
  pVersionStruct->pfnGetDeviceProcAddr = GetDeviceProcAddr;
  pVersionStruct->pfnGetPhysicalDeviceProcAddr = nullptr;
  return VK_SUCCESS;
}
