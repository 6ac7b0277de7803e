// SPDX-License-Identifier: Apache-2.0
// Buffers and memory: what the replay needs to rebuild them, and the address map the pause
// worker reads through. Host-visible memory is mapped once, whole, by the layer, so the worker
// can read it at any pause; the application's own map calls are answered from that mapping.
#include "layer_state.h"
#include "layer_pre_range.h"

#include <cstring>
#include <map>

namespace clastrace::capture {
namespace {

DeviceState& device_of(VkDevice device) { return *find_device(dispatch_key(device)); }

VKAPI_ATTR VkResult VKAPI_CALL AllocateMemory(VkDevice device,
                                              const VkMemoryAllocateInfo* p_allocate_info,
                                              const VkAllocationCallbacks* p_allocator,
                                              VkDeviceMemory* p_memory) {
    DeviceState& d = device_of(device);
    VkResult result = d.next.AllocateMemory(device, p_allocate_info, p_allocator, p_memory);
    if (result != VK_SUCCESS) return result;
    TrackedMemory memory;
    memory.handle = handle_id(*p_memory);
    memory.size = p_allocate_info->allocationSize;
    memory.type_index = p_allocate_info->memoryTypeIndex;
    if (memory.type_index < d.memory_properties.memoryTypeCount)
        memory.property_flags = d.memory_properties.memoryTypes[memory.type_index].propertyFlags;
    // CLASTRACE_FORCE_STAGING: the layer keeps no mapping, as for memory the host cannot map, so
    // the staging path runs on drivers (lavapipe) whose memory is all host visible.
    if ((memory.property_flags & VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT) &&
        !layer_config().force_staging) {
        void* base = nullptr;
        if (d.next.MapMemory(device, *p_memory, 0, VK_WHOLE_SIZE, 0, &base) == VK_SUCCESS)
            memory.host_base = static_cast<uint8_t*>(base);
        else
            log_message(
                LogLevel::kError,
                "could not map host-visible memory 0x%llx; builds reading it are not captured",
                (unsigned long long)memory.handle);
    }
    d.memory_map.add_memory(memory);
    if (d.sink) {
        MemoryRecord record{memory.handle, memory.size, memory.type_index, memory.property_flags,
                            0};
        for (auto* s = (const VkBaseInStructure*)p_allocate_info->pNext; s; s = s->pNext)
            if (s->sType == VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_FLAGS_INFO)
                record.allocate_flags = ((const VkMemoryAllocateFlagsInfo*)s)->flags;
        d.sink->memory_allocated(record);
    }
    return VK_SUCCESS;
}

VKAPI_ATTR void VKAPI_CALL FreeMemory(VkDevice device, VkDeviceMemory memory,
                                      const VkAllocationCallbacks* p_allocator) {
    DeviceState& d = device_of(device);
    if (memory) {
        forget_pre_range_memory(d, handle_id(memory));
        d.host_writes.memory_freed(handle_id(memory));  // unprotects its pages while mapped
        d.memory_map.remove_memory(handle_id(memory));
        if (d.sink) d.sink->memory_freed(handle_id(memory));
    }
    d.next.FreeMemory(device, memory, p_allocator);  // freeing also unmaps the layer's mapping
}

VKAPI_ATTR VkResult VKAPI_CALL MapMemory(VkDevice device, VkDeviceMemory memory,
                                         VkDeviceSize offset, VkDeviceSize size,
                                         VkMemoryMapFlags flags, void** pp_data) {
    DeviceState& d = device_of(device);
    auto tracked = d.memory_map.memory(handle_id(memory));
    if (tracked && tracked->host_base) {
        *pp_data = tracked->host_base + offset;
        return VK_SUCCESS;
    }
    return d.next.MapMemory(device, memory, offset, size, flags, pp_data);
}

VKAPI_ATTR void VKAPI_CALL UnmapMemory(VkDevice device, VkDeviceMemory memory) {
    DeviceState& d = device_of(device);
    auto tracked = d.memory_map.memory(handle_id(memory));
    if (tracked && tracked->host_base) return;  // the layer's mapping lives until vkFreeMemory
    d.next.UnmapMemory(device, memory);
}

VKAPI_ATTR VkResult VKAPI_CALL CreateBuffer(VkDevice device,
                                            const VkBufferCreateInfo* p_create_info,
                                            const VkAllocationCallbacks* p_allocator,
                                            VkBuffer* p_buffer) {
    DeviceState& d = device_of(device);
    VkResult result = d.next.CreateBuffer(device, p_create_info, p_allocator, p_buffer);
    if (result != VK_SUCCESS) return result;
    TrackedBuffer buffer;
    buffer.handle = handle_id(*p_buffer);
    buffer.size = p_create_info->size;
    buffer.usage = p_create_info->usage;
    buffer.flags = p_create_info->flags;
    d.memory_map.add_buffer(buffer);
    if (d.sink) {
        BufferRecord record{
            buffer.handle, buffer.size, buffer.usage, buffer.flags, p_create_info->sharingMode, {}};
        if (p_create_info->sharingMode == VK_SHARING_MODE_CONCURRENT &&
            p_create_info->pQueueFamilyIndices)
            record.queue_families.assign(p_create_info->pQueueFamilyIndices,
                                         p_create_info->pQueueFamilyIndices +
                                             p_create_info->queueFamilyIndexCount);
        d.sink->buffer_created(record);
    }
    return VK_SUCCESS;
}

VKAPI_ATTR void VKAPI_CALL DestroyBuffer(VkDevice device, VkBuffer buffer,
                                         const VkAllocationCallbacks* p_allocator) {
    DeviceState& d = device_of(device);
    if (buffer) {
        d.memory_map.remove_buffer(handle_id(buffer));
        if (d.sink) d.sink->buffer_destroyed(handle_id(buffer));
    }
    d.next.DestroyBuffer(device, buffer, p_allocator);
}

void record_binding(DeviceState& d, VkBuffer buffer, VkDeviceMemory memory, VkDeviceSize offset) {
    d.memory_map.bind_buffer(handle_id(buffer), handle_id(memory), offset);
    if (d.sink) d.sink->buffer_bound({handle_id(buffer), handle_id(memory), offset});
}

VKAPI_ATTR VkResult VKAPI_CALL BindBufferMemory(VkDevice device, VkBuffer buffer,
                                                VkDeviceMemory memory, VkDeviceSize offset) {
    DeviceState& d = device_of(device);
    VkResult result = d.next.BindBufferMemory(device, buffer, memory, offset);
    if (result == VK_SUCCESS) record_binding(d, buffer, memory, offset);
    return result;
}

VkResult bind_buffer_memory2(VkDevice device, uint32_t count, const VkBindBufferMemoryInfo* infos,
                             bool khr) {
    DeviceState& d = device_of(device);
    VkResult result = khr ? d.next.BindBufferMemory2KHR(device, count, infos)
                          : d.next.BindBufferMemory2(device, count, infos);
    if (result == VK_SUCCESS)
        for (uint32_t i = 0; i < count; ++i)
            record_binding(d, infos[i].buffer, infos[i].memory, infos[i].memoryOffset);
    return result;
}
VKAPI_ATTR VkResult VKAPI_CALL BindBufferMemory2(VkDevice device, uint32_t count,
                                                 const VkBindBufferMemoryInfo* infos) {
    return bind_buffer_memory2(device, count, infos, false);
}
VKAPI_ATTR VkResult VKAPI_CALL BindBufferMemory2KHR(VkDevice device, uint32_t count,
                                                    const VkBindBufferMemoryInfo* infos) {
    return bind_buffer_memory2(device, count, infos, true);
}

VkDeviceAddress buffer_address(VkDevice device, const VkBufferDeviceAddressInfo* p_info,
                               PFN_vkGetBufferDeviceAddress next) {
    DeviceState& d = device_of(device);
    VkDeviceAddress address = next(device, p_info);
    d.memory_map.set_buffer_address(handle_id(p_info->buffer), address);
    if (d.sink) d.sink->buffer_address_queried({handle_id(p_info->buffer), address});
    return address;
}
VKAPI_ATTR VkDeviceAddress VKAPI_CALL
GetBufferDeviceAddress(VkDevice device, const VkBufferDeviceAddressInfo* p_info) {
    return buffer_address(device, p_info, device_of(device).next.GetBufferDeviceAddress);
}
VKAPI_ATTR VkDeviceAddress VKAPI_CALL
GetBufferDeviceAddressKHR(VkDevice device, const VkBufferDeviceAddressInfo* p_info) {
    return buffer_address(device, p_info, device_of(device).next.GetBufferDeviceAddressKHR);
}
VKAPI_ATTR VkDeviceAddress VKAPI_CALL
GetBufferDeviceAddressEXT(VkDevice device, const VkBufferDeviceAddressInfo* p_info) {
    return buffer_address(device, p_info, device_of(device).next.GetBufferDeviceAddressEXT);
}

}  // namespace

PFN_vkVoidFunction resource_hook(const char* name) {
    static const std::map<std::string, PFN_vkVoidFunction, std::less<>> kHooks = {
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
    auto it = kHooks.find(name);
    return it == kHooks.end() ? nullptr : it->second;
}

}  // namespace clastrace::capture
