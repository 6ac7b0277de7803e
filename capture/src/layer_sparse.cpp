// SPDX-License-Identifier: Apache-2.0
// vkQueueBindSparse: binds memory under sparse buffers (vk_lod_clusters places cluster
// structures in them). The layer follows the buffer binds in its memory map, so the device
// addresses of a sparse buffer resolve to the memory bound under them, and records each call
// in queue order with the submissions (its semaphores and fence order it like one). Image
// binds are passed on and only counted in the record.
#include "layer_state.h"

#include <cstring>

namespace clastrace::capture {
namespace {

// The buffer's device address, asked from the driver when the application has not asked yet
// (replay places the sparse buffer there); 0 when the buffer cannot have one.
uint64_t sparse_buffer_address(DeviceState& d, VkBuffer buffer) {
    const std::optional<TrackedBuffer> tracked = d.memory_map.buffer(handle_id(buffer));
    if (!tracked) return 0;
    if (tracked->address != 0) return tracked->address;
    if (!(tracked->usage & VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT)) return 0;
    PFN_vkGetBufferDeviceAddress get = d.next.GetBufferDeviceAddress
                                           ? d.next.GetBufferDeviceAddress
                                           : d.next.GetBufferDeviceAddressKHR;
    if (!get) return 0;
    VkBufferDeviceAddressInfo info{VK_STRUCTURE_TYPE_BUFFER_DEVICE_ADDRESS_INFO, nullptr, buffer};
    const VkDeviceAddress address = get(d.device, &info);
    d.memory_map.set_buffer_address(handle_id(buffer), address);
    return address;
}

void follow_buffer_binds(DeviceState& d, const VkBindSparseInfo& info) {
    for (uint32_t b = 0; b < info.bufferBindCount; ++b) {
        const VkSparseBufferMemoryBindInfo& buffer = info.pBufferBinds[b];
        for (uint32_t k = 0; k < buffer.bindCount; ++k) {
            const VkSparseMemoryBind& m = buffer.pBinds[k];
            d.memory_map.bind_sparse(handle_id(buffer.buffer), m.resourceOffset, m.size,
                                     handle_id(m.memory), m.memoryOffset);
        }
    }
}

VKAPI_ATTR VkResult VKAPI_CALL QueueBindSparse(VkQueue queue, uint32_t bind_info_count,
                                               const VkBindSparseInfo* p_bind_info, VkFence fence) {
    DeviceState& d = *find_device(dispatch_key(queue));
    const VkResult result = d.next.QueueBindSparse(queue, bind_info_count, p_bind_info, fence);
    if (result != VK_SUCCESS) return result;  // nothing reached the queue
    // The map follows the binds in call order: a build recorded against the buffer reads the
    // memory bound by the binds made before its submission.
    for (uint32_t i = 0; i < bind_info_count; ++i) follow_buffer_binds(d, p_bind_info[i]);
    if (d.capturing_now()) {
        SparseBindRecord record;
        record.queue = queue;
        record.infos = p_bind_info;
        record.info_count = bind_info_count;
        record.fence = fence;
        record.result = result;
        record.address_of = [&d](VkBuffer buffer) { return sparse_buffer_address(d, buffer); };
        d.sink->sparse_bound(record);
    }
    return result;
}

}  // namespace

PFN_vkVoidFunction sparse_hook(const char* name) {
    if (std::strcmp(name, "vkQueueBindSparse") == 0) return (PFN_vkVoidFunction)QueueBindSparse;
    return nullptr;
}

}  // namespace clastrace::capture
