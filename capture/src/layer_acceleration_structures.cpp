// NV and KHR acceleration-structure objects (creation, memory, handles and addresses, for the
// replay to rebuild them and translate instance records), the queues' families, and the ray
// check that traces rays against a top level after the submission that built it.
#include "command_buffer_log.h"
#include "layer_state.h"

#include <chrono>
#include <cinttypes>
#include <cstring>
#include <map>

namespace clastrace::capture {
namespace {

DeviceState& deviceOf(VkDevice device) { return *findDevice(dispatchKey(device)); }

// ---- NV objects ----------------------------------------------------------------------------

VKAPI_ATTR VkResult VKAPI_CALL CreateAccelerationStructureNV(VkDevice device,
                                                             const VkAccelerationStructureCreateInfoNV* pCreateInfo,
                                                             const VkAllocationCallbacks* pAllocator,
                                                             VkAccelerationStructureNV* pAccelerationStructure) {
  DeviceState& d = deviceOf(device);
  VkResult result = d.next.CreateAccelerationStructureNV(device, pCreateInfo, pAllocator, pAccelerationStructure);
  if (result != VK_SUCCESS || !d.sink) return result;
  AccelerationStructureRecord r;
  r.accelerationStructure = handleId(*pAccelerationStructure);
  r.type = uint32_t(pCreateInfo->info.type);
  r.compactedSize = pCreateInfo->compactedSize;
  r.infoType = uint32_t(pCreateInfo->info.type);
  r.infoFlags = pCreateInfo->info.flags;
  r.instanceCount = pCreateInfo->info.instanceCount;
  for (uint32_t i = 0; i < pCreateInfo->info.geometryCount; ++i) {
    VkGeometryNV g = pCreateInfo->info.pGeometries[i];
    g.pNext = nullptr;
    g.geometry.triangles.pNext = nullptr;
    g.geometry.aabbs.pNext = nullptr;
    r.geometries.push_back(g);
  }
  d.sink->accelerationStructureCreated(r);
  return result;
}

VKAPI_ATTR void VKAPI_CALL DestroyAccelerationStructureNV(VkDevice device, VkAccelerationStructureNV as,
                                                          const VkAllocationCallbacks* pAllocator) {
  DeviceState& d = deviceOf(device);
  if (as) {
    d.nvScene.forget(handleId(as));
    if (d.sink) d.sink->accelerationStructureDestroyed(handleId(as));
  }
  d.next.DestroyAccelerationStructureNV(device, as, pAllocator);
}

VKAPI_ATTR VkResult VKAPI_CALL BindAccelerationStructureMemoryNV(VkDevice device, uint32_t count,
                                                                 const VkBindAccelerationStructureMemoryInfoNV* infos) {
  DeviceState& d = deviceOf(device);
  VkResult result = d.next.BindAccelerationStructureMemoryNV(device, count, infos);
  if (result == VK_SUCCESS && d.sink)
    for (uint32_t i = 0; i < count; ++i)
      d.sink->accelerationStructureBound(
          {handleId(infos[i].accelerationStructure), handleId(infos[i].memory), infos[i].memoryOffset});
  return result;
}

VKAPI_ATTR VkResult VKAPI_CALL GetAccelerationStructureHandleNV(VkDevice device, VkAccelerationStructureNV as,
                                                                size_t dataSize, void* pData) {
  DeviceState& d = deviceOf(device);
  VkResult result = d.next.GetAccelerationStructureHandleNV(device, as, dataSize, pData);
  if (result != VK_SUCCESS || dataSize < sizeof(uint64_t)) return result;
  uint64_t handle;
  std::memcpy(&handle, pData, sizeof handle);
  d.nvScene.setHandle(handleId(as), handle);
  if (d.sink) d.sink->accelerationStructureAddressQueried({handleId(as), handle});
  return result;
}

VKAPI_ATTR void VKAPI_CALL GetAccelerationStructureMemoryRequirementsNV(
    VkDevice device, const VkAccelerationStructureMemoryRequirementsInfoNV* pInfo, VkMemoryRequirements2KHR* pOut) {
  DeviceState& d = deviceOf(device);
  d.next.GetAccelerationStructureMemoryRequirementsNV(device, pInfo, pOut);
  if (!d.sink) return;
  const VkMemoryRequirements& m = pOut->memoryRequirements;
  d.sink->accelerationStructureMemoryRequirements(
      {handleId(pInfo->accelerationStructure), uint32_t(pInfo->type), m.size, m.alignment, m.memoryTypeBits});
}

// ---- KHR objects ---------------------------------------------------------------------------

VKAPI_ATTR VkResult VKAPI_CALL CreateAccelerationStructureKHR(VkDevice device,
                                                              const VkAccelerationStructureCreateInfoKHR* pCreateInfo,
                                                              const VkAllocationCallbacks* pAllocator,
                                                              VkAccelerationStructureKHR* pAccelerationStructure) {
  DeviceState& d = deviceOf(device);
  VkResult result = d.next.CreateAccelerationStructureKHR(device, pCreateInfo, pAllocator, pAccelerationStructure);
  if (result != VK_SUCCESS || !d.sink) return result;
  AccelerationStructureRecord r;
  r.accelerationStructure = handleId(*pAccelerationStructure);
  r.khr = true;
  r.type = uint32_t(pCreateInfo->type);
  r.buffer = handleId(pCreateInfo->buffer);
  r.offset = pCreateInfo->offset;
  r.size = pCreateInfo->size;
  r.createFlags = pCreateInfo->createFlags;
  d.sink->accelerationStructureCreated(r);
  return result;
}

VKAPI_ATTR void VKAPI_CALL DestroyAccelerationStructureKHR(VkDevice device, VkAccelerationStructureKHR as,
                                                           const VkAllocationCallbacks* pAllocator) {
  DeviceState& d = deviceOf(device);
  if (as && d.sink) d.sink->accelerationStructureDestroyed(handleId(as));
  d.next.DestroyAccelerationStructureKHR(device, as, pAllocator);
}

VKAPI_ATTR VkDeviceAddress VKAPI_CALL GetAccelerationStructureDeviceAddressKHR(
    VkDevice device, const VkAccelerationStructureDeviceAddressInfoKHR* pInfo) {
  DeviceState& d = deviceOf(device);
  VkDeviceAddress address = d.next.GetAccelerationStructureDeviceAddressKHR(device, pInfo);
  if (d.sink) d.sink->accelerationStructureAddressQueried({handleId(pInfo->accelerationStructure), address});
  return address;
}

// ---- Queues ------------------------------------------------------------------------------

VKAPI_ATTR void VKAPI_CALL GetDeviceQueue(VkDevice device, uint32_t family, uint32_t index, VkQueue* pQueue) {
  DeviceState& d = deviceOf(device);
  d.next.GetDeviceQueue(device, family, index, pQueue);
  std::lock_guard lock(d.queuesMutex);
  if (*pQueue) {
    d.queueFamilies[*pQueue] = family;
    d.queueIndices[*pQueue] = index;
  }
}

VKAPI_ATTR void VKAPI_CALL GetDeviceQueue2(VkDevice device, const VkDeviceQueueInfo2* pInfo, VkQueue* pQueue) {
  DeviceState& d = deviceOf(device);
  d.next.GetDeviceQueue2(device, pInfo, pQueue);
  std::lock_guard lock(d.queuesMutex);
  if (*pQueue) {
    d.queueFamilies[*pQueue] = pInfo->queueFamilyIndex;
    d.queueIndices[*pQueue] = pInfo->queueIndex;
  }
}

// Waits until everything submitted to `queue` so far has completed (an empty submission's fence).
bool waitForQueue(DeviceState& d, VkQueue queue, std::string& why) {
  auto createFence = (PFN_vkCreateFence)d.next.GetDeviceProcAddr(d.device, "vkCreateFence");
  auto destroyFence = (PFN_vkDestroyFence)d.next.GetDeviceProcAddr(d.device, "vkDestroyFence");
  auto waitForFences = (PFN_vkWaitForFences)d.next.GetDeviceProcAddr(d.device, "vkWaitForFences");
  if (!createFence || !destroyFence || !waitForFences) {
    why = "the driver has no fence functions";
    return false;
  }
  VkFenceCreateInfo info{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO, nullptr, 0};
  VkFence fence;
  if (createFence(d.device, &info, nullptr, &fence) != VK_SUCCESS) {
    why = "vkCreateFence failed";
    return false;
  }
  VkResult result = d.next.QueueSubmit(queue, 0, nullptr, fence);
  if (result == VK_SUCCESS) result = waitForFences(d.device, 1, &fence, VK_TRUE, 30'000'000'000ull);
  if (result != VK_SUCCESS) {
    why = "waiting for the submission failed with VkResult " + std::to_string(int(result));
    return false;  // the fence may still be pending: leak it rather than destroy it in use
  }
  destroyFence(d.device, fence, nullptr);
  return true;
}

}  // namespace

void runRayChecks(DeviceState& d, VkQueue queue, uint64_t submissionIndex, const std::vector<uint64_t>& topLevels) {
  const uint32_t rayCount = layerConfig().rayCheckRays;
  if (rayCount == 0 || topLevels.empty() || !d.sink) return;
  if (!d.nvRayTracingEnabled) {
    logMessage(LogLevel::Error, "ray check skipped: the device was created without VK_NV_ray_tracing");
    return;
  }
  uint32_t family;
  {
    std::lock_guard lock(d.queuesMutex);
    auto it = d.queueFamilies.find(queue);
    if (it == d.queueFamilies.end()) {
      logMessage(LogLevel::Error, "ray check skipped: the queue's family is unknown (queue not from vkGetDeviceQueue)");
      return;
    }
    family = it->second;
  }
  std::string why;
  // The worker reads each build's inputs at its pause; once the queue is idle every pause of
  // this submission was handled, so the scene model holds what the builds read.
  if (!waitForQueue(d, queue, why)) {
    logMessage(LogLevel::Error, "ray check after submission %llu skipped: %s", (unsigned long long)submissionIndex,
               why.c_str());
    return;
  }
  NvRayTracerContext context;
  context.device = d.device;
  context.queue = queue;
  context.queueFamilyIndex = family;
  context.getDeviceProcAddr = d.next.GetDeviceProcAddr;
  context.memoryProperties = d.memoryProperties;
  context.rayTracingProperties = d.rayTracingPropertiesNV;
  context.setCommandBufferDispatch = true;
  for (uint64_t topLevel : topLevels) {
    const auto started = std::chrono::steady_clock::now();
    RayCheckRecord record;
    record.accelerationStructure = topLevel;
    record.submissionIndex = submissionIndex;
    record.label = kNvRayCheckRule;
    NvTraceScene scene;
    if (!d.nvScene.prepare(topLevel, rayCount, scene, record.rays, record.deviceHandle, why)) {
      logMessage(LogLevel::Error, "ray check of top level 0x%llx skipped: %s", (unsigned long long)topLevel, why.c_str());
      continue;
    }
    if (!traceRaysNV(context, (VkAccelerationStructureNV)topLevel, scene, record.rays, record.hits, why)) {
      logMessage(LogLevel::Error, "ray check of top level 0x%llx failed: %s", (unsigned long long)topLevel, why.c_str());
      continue;
    }
    size_t hits = 0;
    for (const NvRayHit& h : record.hits) hits += h.hit != 0;
    const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - started).count();
    logMessage(LogLevel::Info, "ray check of top level 0x%llx after submission %llu: %zu rays, %zu hits, %.2f ms",
               (unsigned long long)topLevel, (unsigned long long)submissionIndex, record.rays.size(), hits, ms);
    d.sink->rayQueryChecked(record);
  }
}

PFN_vkVoidFunction accelerationStructureHook(const char* name) {
#define HOOK(fn) {"vk" #fn, (PFN_vkVoidFunction)fn}
  static const std::map<std::string, PFN_vkVoidFunction, std::less<>> hooks = {
      HOOK(CreateAccelerationStructureNV), HOOK(DestroyAccelerationStructureNV),
      HOOK(BindAccelerationStructureMemoryNV), HOOK(GetAccelerationStructureHandleNV),
      HOOK(GetAccelerationStructureMemoryRequirementsNV), HOOK(CreateAccelerationStructureKHR),
      HOOK(DestroyAccelerationStructureKHR), HOOK(GetAccelerationStructureDeviceAddressKHR),
      HOOK(GetDeviceQueue), HOOK(GetDeviceQueue2),
  };
#undef HOOK
  auto it = hooks.find(name);
  return it == hooks.end() ? nullptr : it->second;
}

}  // namespace clastrace::capture
