// Buffers and memory: what the replay needs to rebuild them, and the address map the pause
// worker reads through. Host-visible memory is mapped once, whole, by the layer, so the worker
// can read it at any pause; the application's own map calls are answered from that mapping.
#include "layer_state.h"

#include <cstring>
#include <map>

namespace clastrace::capture {
namespace {

DeviceState& deviceOf(VkDevice device) { return *findDevice(dispatchKey(device)); }

VKAPI_ATTR VkResult VKAPI_CALL AllocateMemory(VkDevice device, const VkMemoryAllocateInfo* pAllocateInfo,
                                              const VkAllocationCallbacks* pAllocator, VkDeviceMemory* pMemory) {
  DeviceState& d = deviceOf(device);
  VkResult result = d.next.AllocateMemory(device, pAllocateInfo, pAllocator, pMemory);
  if (result != VK_SUCCESS) return result;
  TrackedMemory memory;
  memory.handle = handleId(*pMemory);
  memory.size = pAllocateInfo->allocationSize;
  memory.typeIndex = pAllocateInfo->memoryTypeIndex;
  if (memory.typeIndex < d.memoryProperties.memoryTypeCount)
    memory.propertyFlags = d.memoryProperties.memoryTypes[memory.typeIndex].propertyFlags;
  // CLASTRACE_FORCE_STAGING: the layer keeps no mapping, as for memory the host cannot map, so
  // the staging path runs on drivers (lavapipe) whose memory is all host visible.
  if ((memory.propertyFlags & VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT) && !layerConfig().forceStaging) {
    void* base = nullptr;
    if (d.next.MapMemory(device, *pMemory, 0, VK_WHOLE_SIZE, 0, &base) == VK_SUCCESS)
      memory.hostBase = static_cast<uint8_t*>(base);
    else
      logMessage(LogLevel::Error, "could not map host-visible memory 0x%llx; builds reading it are not captured",
                 (unsigned long long)memory.handle);
  }
  d.memoryMap.addMemory(memory);
  if (d.sink) {
    MemoryRecord record{memory.handle, memory.size, memory.typeIndex, memory.propertyFlags, 0};
    for (auto* s = (const VkBaseInStructure*)pAllocateInfo->pNext; s; s = s->pNext)
      if (s->sType == VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_FLAGS_INFO)
        record.allocateFlags = ((const VkMemoryAllocateFlagsInfo*)s)->flags;
    d.sink->memoryAllocated(record);
  }
  return VK_SUCCESS;
}

VKAPI_ATTR void VKAPI_CALL FreeMemory(VkDevice device, VkDeviceMemory memory, const VkAllocationCallbacks* pAllocator) {
  DeviceState& d = deviceOf(device);
  if (memory) {
    d.memoryMap.removeMemory(handleId(memory));
    if (d.sink) d.sink->memoryFreed(handleId(memory));
  }
  d.next.FreeMemory(device, memory, pAllocator);  // freeing also unmaps the layer's mapping
}

VKAPI_ATTR VkResult VKAPI_CALL MapMemory(VkDevice device, VkDeviceMemory memory, VkDeviceSize offset,
                                         VkDeviceSize size, VkMemoryMapFlags flags, void** ppData) {
  DeviceState& d = deviceOf(device);
  auto tracked = d.memoryMap.memory(handleId(memory));
  if (tracked && tracked->hostBase) {
    *ppData = tracked->hostBase + offset;
    return VK_SUCCESS;
  }
  return d.next.MapMemory(device, memory, offset, size, flags, ppData);
}

VKAPI_ATTR void VKAPI_CALL UnmapMemory(VkDevice device, VkDeviceMemory memory) {
  DeviceState& d = deviceOf(device);
  auto tracked = d.memoryMap.memory(handleId(memory));
  if (tracked && tracked->hostBase) return;  // the layer's mapping lives until vkFreeMemory
  d.next.UnmapMemory(device, memory);
}

VKAPI_ATTR VkResult VKAPI_CALL CreateBuffer(VkDevice device, const VkBufferCreateInfo* pCreateInfo,
                                            const VkAllocationCallbacks* pAllocator, VkBuffer* pBuffer) {
  DeviceState& d = deviceOf(device);
  VkResult result = d.next.CreateBuffer(device, pCreateInfo, pAllocator, pBuffer);
  if (result != VK_SUCCESS) return result;
  TrackedBuffer buffer;
  buffer.handle = handleId(*pBuffer);
  buffer.size = pCreateInfo->size;
  buffer.usage = pCreateInfo->usage;
  buffer.flags = pCreateInfo->flags;
  d.memoryMap.addBuffer(buffer);
  if (d.sink) {
    BufferRecord record{buffer.handle, buffer.size, buffer.usage, buffer.flags, pCreateInfo->sharingMode, {}};
    if (pCreateInfo->sharingMode == VK_SHARING_MODE_CONCURRENT && pCreateInfo->pQueueFamilyIndices)
      record.queueFamilies.assign(pCreateInfo->pQueueFamilyIndices,
                                  pCreateInfo->pQueueFamilyIndices + pCreateInfo->queueFamilyIndexCount);
    d.sink->bufferCreated(record);
  }
  return VK_SUCCESS;
}

VKAPI_ATTR void VKAPI_CALL DestroyBuffer(VkDevice device, VkBuffer buffer, const VkAllocationCallbacks* pAllocator) {
  DeviceState& d = deviceOf(device);
  if (buffer) {
    d.memoryMap.removeBuffer(handleId(buffer));
    if (d.sink) d.sink->bufferDestroyed(handleId(buffer));
  }
  d.next.DestroyBuffer(device, buffer, pAllocator);
}

void recordBinding(DeviceState& d, VkBuffer buffer, VkDeviceMemory memory, VkDeviceSize offset) {
  d.memoryMap.bindBuffer(handleId(buffer), handleId(memory), offset);
  if (d.sink) d.sink->bufferBound({handleId(buffer), handleId(memory), offset});
}

VKAPI_ATTR VkResult VKAPI_CALL BindBufferMemory(VkDevice device, VkBuffer buffer, VkDeviceMemory memory,
                                                VkDeviceSize offset) {
  DeviceState& d = deviceOf(device);
  VkResult result = d.next.BindBufferMemory(device, buffer, memory, offset);
  if (result == VK_SUCCESS) recordBinding(d, buffer, memory, offset);
  return result;
}

VkResult bindBufferMemory2(VkDevice device, uint32_t count, const VkBindBufferMemoryInfo* infos, bool khr) {
  DeviceState& d = deviceOf(device);
  VkResult result = khr ? d.next.BindBufferMemory2KHR(device, count, infos) : d.next.BindBufferMemory2(device, count, infos);
  if (result == VK_SUCCESS)
    for (uint32_t i = 0; i < count; ++i) recordBinding(d, infos[i].buffer, infos[i].memory, infos[i].memoryOffset);
  return result;
}
VKAPI_ATTR VkResult VKAPI_CALL BindBufferMemory2(VkDevice device, uint32_t count, const VkBindBufferMemoryInfo* infos) {
  return bindBufferMemory2(device, count, infos, false);
}
VKAPI_ATTR VkResult VKAPI_CALL BindBufferMemory2KHR(VkDevice device, uint32_t count,
                                                    const VkBindBufferMemoryInfo* infos) {
  return bindBufferMemory2(device, count, infos, true);
}

VkDeviceAddress bufferAddress(VkDevice device, const VkBufferDeviceAddressInfo* pInfo, PFN_vkGetBufferDeviceAddress next) {
  DeviceState& d = deviceOf(device);
  VkDeviceAddress address = next(device, pInfo);
  d.memoryMap.setBufferAddress(handleId(pInfo->buffer), address);
  if (d.sink) d.sink->bufferAddressQueried({handleId(pInfo->buffer), address});
  return address;
}
VKAPI_ATTR VkDeviceAddress VKAPI_CALL GetBufferDeviceAddress(VkDevice device, const VkBufferDeviceAddressInfo* pInfo) {
  return bufferAddress(device, pInfo, deviceOf(device).next.GetBufferDeviceAddress);
}
VKAPI_ATTR VkDeviceAddress VKAPI_CALL GetBufferDeviceAddressKHR(VkDevice device, const VkBufferDeviceAddressInfo* pInfo) {
  return bufferAddress(device, pInfo, deviceOf(device).next.GetBufferDeviceAddressKHR);
}
VKAPI_ATTR VkDeviceAddress VKAPI_CALL GetBufferDeviceAddressEXT(VkDevice device, const VkBufferDeviceAddressInfo* pInfo) {
  return bufferAddress(device, pInfo, deviceOf(device).next.GetBufferDeviceAddressEXT);
}

}  // namespace

PFN_vkVoidFunction resourceHook(const char* name) {
  static const std::map<std::string, PFN_vkVoidFunction, std::less<>> hooks = {
      {"vkAllocateMemory", (PFN_vkVoidFunction)AllocateMemory},
      {"vkFreeMemory", (PFN_vkVoidFunction)FreeMemory},
      {"vkMapMemory", (PFN_vkVoidFunction)MapMemory},
      {"vkUnmapMemory", (PFN_vkVoidFunction)UnmapMemory},
      {"vkCreateBuffer", (PFN_vkVoidFunction)CreateBuffer},
      {"vkDestroyBuffer", (PFN_vkVoidFunction)DestroyBuffer},
      {"vkBindBufferMemory", (PFN_vkVoidFunction)BindBufferMemory},
      {"vkBindBufferMemory2", (PFN_vkVoidFunction)BindBufferMemory2},
      {"vkBindBufferMemory2KHR", (PFN_vkVoidFunction)BindBufferMemory2KHR},
      {"vkGetBufferDeviceAddress", (PFN_vkVoidFunction)GetBufferDeviceAddress},
      {"vkGetBufferDeviceAddressKHR", (PFN_vkVoidFunction)GetBufferDeviceAddressKHR},
      {"vkGetBufferDeviceAddressEXT", (PFN_vkVoidFunction)GetBufferDeviceAddressEXT},
  };
  auto it = hooks.find(name);
  return it == hooks.end() ? nullptr : it->second;
}

}  // namespace clastrace::capture
