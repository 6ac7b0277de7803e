// SPDX-License-Identifier: Apache-2.0
#include "pause_staging.h"

#include "layer_state.h"

#include <atomic>

namespace clastrace::capture {

const StagedBuffer* StagingSet::find(uint64_t handle) const {
    for (const StagedBuffer& b : buffers)
        if (b.buffer.handle == handle) return &b;
    return nullptr;
}

namespace {

void report_once(const char* what, VkResult result) {
    static std::atomic<bool> reported{false};
    if (reported.exchange(true)) return;
    log_message(
        LogLevel::kError,
        "staging for memory the host cannot map: %s failed (VkResult %d); builds reading such "
        "memory are captured without it",
        what, int(result));
}

}  // namespace

std::shared_ptr<StagingSet> create_staging(DeviceState& d) {
    std::vector<TrackedBuffer> unmapped = d.memory_map.unmapped_addressed_buffers(kStagedUsage);
    if (unmapped.empty()) return nullptr;
    auto staging = std::make_shared<StagingSet>();
    VkDeviceSize size = 0;
    for (const TrackedBuffer& b : unmapped) {
        staging->buffers.push_back({b, size});
        size += (b.size + 255) / 256 * 256;
    }
    VkBufferCreateInfo info{};
    info.sType = VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO;
    info.size = size;
    info.usage = VK_BUFFER_USAGE_TRANSFER_SRC_BIT | VK_BUFFER_USAGE_TRANSFER_DST_BIT;
    info.sharingMode = VK_SHARING_MODE_EXCLUSIVE;
    VkResult r = d.next.CreateBuffer(d.device, &info, nullptr, &staging->buffer);
    if (r != VK_SUCCESS) {
        report_once("vkCreateBuffer", r);
        return nullptr;
    }
    VkMemoryRequirements requirements{};
    d.next.GetBufferMemoryRequirements(d.device, staging->buffer, &requirements);
    // The host reads every staged byte: cached coherent memory if there is one (uncached,
    // write-combined host-visible memory reads several times slower), else coherent (no
    // flush/invalidate), else any host-visible.
    uint32_t type = UINT32_MAX;
    const VkMemoryPropertyFlags choices[3] = {VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT |
                                                  VK_MEMORY_PROPERTY_HOST_COHERENT_BIT |
                                                  VK_MEMORY_PROPERTY_HOST_CACHED_BIT,
                                              VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT |
                                                  VK_MEMORY_PROPERTY_HOST_COHERENT_BIT,
                                              VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT};
    for (VkMemoryPropertyFlags want : choices) {
        for (uint32_t t = 0; t < d.memory_properties.memoryTypeCount && type == UINT32_MAX; ++t)
            if ((requirements.memoryTypeBits & (1u << t)) &&
                (d.memory_properties.memoryTypes[t].propertyFlags & want) == want)
                type = t;
        if (type != UINT32_MAX) break;
    }
    VkMemoryAllocateInfo allocate{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO, nullptr,
                                  requirements.size, type};
    r = type == UINT32_MAX ? VK_ERROR_FEATURE_NOT_PRESENT
                           : d.next.AllocateMemory(d.device, &allocate, nullptr, &staging->memory);
    void* host = nullptr;
    if (r == VK_SUCCESS) r = d.next.BindBufferMemory(d.device, staging->buffer, staging->memory, 0);
    if (r == VK_SUCCESS)
        r = d.next.MapMemory(d.device, staging->memory, 0, VK_WHOLE_SIZE, 0, &host);
    if (r != VK_SUCCESS) {
        report_once("allocating host-visible memory", r);
        destroy_staging(d, *staging);
        return nullptr;
    }
    staging->host = static_cast<uint8_t*>(host);
    staging->coherent =
        d.memory_properties.memoryTypes[type].propertyFlags & VK_MEMORY_PROPERTY_HOST_COHERENT_BIT;
    staging->cached =
        d.memory_properties.memoryTypes[type].propertyFlags & VK_MEMORY_PROPERTY_HOST_CACHED_BIT;
    return staging;
}

void destroy_staging(DeviceState& d, StagingSet& staging) {
    if (staging.buffer) d.next.DestroyBuffer(d.device, staging.buffer, nullptr);
    if (staging.memory) d.next.FreeMemory(d.device, staging.memory, nullptr);  // unmaps too
    staging.buffer = VK_NULL_HANDLE;
    staging.memory = VK_NULL_HANDLE;
    staging.host = nullptr;
}

void record_copies_to_staging(DeviceState& d, VkCommandBuffer cb, const StagingSet& staging) {
    // Every earlier write to the staged buffers is complete before the copies read them.
    const VkMemoryBarrier before{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr,
                                 VK_ACCESS_MEMORY_WRITE_BIT, VK_ACCESS_TRANSFER_READ_BIT};
    d.next.CmdPipelineBarrier(cb, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT,
                              VK_PIPELINE_STAGE_TRANSFER_BIT, 0, 1, &before, 0, nullptr, 0,
                              nullptr);
    for (const StagedBuffer& b : staging.buffers) {
        const VkBufferCopy region{0, b.offset, b.buffer.size};
        d.next.CmdCopyBuffer(cb, (VkBuffer)b.buffer.handle, staging.buffer, 1, &region);
    }
}

void record_copies_from_staging(DeviceState& d, VkCommandBuffer cb, const StagingSet& staging) {
    for (const StagedBuffer& b : staging.buffers) {
        const VkBufferCopy region{b.offset, 0, b.buffer.size};
        d.next.CmdCopyBuffer(cb, staging.buffer, (VkBuffer)b.buffer.handle, 1, &region);
    }
    // The application's later commands see the bytes as the worker left them.
    const VkMemoryBarrier after{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr,
                                VK_ACCESS_TRANSFER_WRITE_BIT,
                                VK_ACCESS_MEMORY_READ_BIT | VK_ACCESS_MEMORY_WRITE_BIT};
    d.next.CmdPipelineBarrier(cb, VK_PIPELINE_STAGE_TRANSFER_BIT,
                              VK_PIPELINE_STAGE_ALL_COMMANDS_BIT, 0, 1, &after, 0, nullptr, 0,
                              nullptr);
}

}  // namespace clastrace::capture
