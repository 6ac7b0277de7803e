// SPDX-License-Identifier: Apache-2.0
#include <clastrace/traces/sparse_conversions.h>

#include "vk_handle_record.h"

#include <clastrace/common/enum_bits.h>

#include <type_traits>

namespace clastrace::traces {

namespace {

using detail::handle_from_record;
using detail::handle_to_record;

const VkTimelineSemaphoreSubmitInfo* timeline_values(const VkBindSparseInfo& info) {
    for (auto* s = static_cast<const VkBaseInStructure*>(info.pNext); s; s = s->pNext)
        if (common::enum_bits(s->sType) == VK_STRUCTURE_TYPE_TIMELINE_SEMAPHORE_SUBMIT_INFO)
            return reinterpret_cast<const VkTimelineSemaphoreSubmitInfo*>(s);
    return nullptr;
}

std::vector<fbs::SemaphoreOp> semaphore_ops(const VkSemaphore* semaphores, uint32_t count,
                                            const uint64_t* values, uint32_t value_count) {
    std::vector<fbs::SemaphoreOp> ops;
    ops.reserve(count);
    for (uint32_t i = 0; i < count; ++i)
        ops.emplace_back(handle_to_record(semaphores[i]), values && i < value_count ? values[i] : 0,
                         0, 0);
    return ops;
}

}  // namespace

std::unique_ptr<fbs::SparseBindBatchT> sparse_batch_to_record(
    const VkBindSparseInfo& info, const std::function<uint64_t(VkBuffer)>& address_of) {
    auto batch = std::make_unique<fbs::SparseBindBatchT>();
    const VkTimelineSemaphoreSubmitInfo* timeline = timeline_values(info);
    batch->wait_semaphores = semaphore_ops(info.pWaitSemaphores, info.waitSemaphoreCount,
                                           timeline ? timeline->pWaitSemaphoreValues : nullptr,
                                           timeline ? timeline->waitSemaphoreValueCount : 0);
    batch->signal_semaphores = semaphore_ops(info.pSignalSemaphores, info.signalSemaphoreCount,
                                             timeline ? timeline->pSignalSemaphoreValues : nullptr,
                                             timeline ? timeline->signalSemaphoreValueCount : 0);
    for (uint32_t b = 0; b < info.bufferBindCount; ++b) {
        const VkSparseBufferMemoryBindInfo& buffer = info.pBufferBinds[b];
        auto out = std::make_unique<fbs::SparseBufferBindT>();
        out->buffer = handle_to_record(buffer.buffer);
        out->device_address = address_of ? address_of(buffer.buffer) : 0;
        for (uint32_t k = 0; k < buffer.bindCount; ++k) {
            const VkSparseMemoryBind& m = buffer.pBinds[k];
            out->binds.emplace_back(m.resourceOffset, m.size, handle_to_record(m.memory),
                                    m.memoryOffset, m.flags);
        }
        batch->buffer_binds.push_back(std::move(out));
    }
    batch->image_opaque_bind_count = info.imageOpaqueBindCount;
    batch->image_bind_count = info.imageBindCount;
    return batch;
}

fbs::QueueBindSparseT queue_bind_sparse_to_record(
    VkQueue queue, std::span<const VkBindSparseInfo> infos, VkFence fence, VkResult result,
    const std::function<uint64_t(VkBuffer)>& address_of) {
    fbs::QueueBindSparseT record;
    record.queue = reinterpret_cast<uintptr_t>(queue);
    for (const VkBindSparseInfo& info : infos)
        record.batches.push_back(sparse_batch_to_record(info, address_of));
    record.fence = handle_to_record(fence);
    record.result = result;
    return record;
}

VkSparseMemoryBind sparse_bind_from_record(const fbs::SparseMemoryBind& bind) {
    VkSparseMemoryBind out{};
    out.resourceOffset = bind.resource_offset();
    out.size = bind.size();
    out.memory = handle_from_record<VkDeviceMemory>(bind.memory());
    out.memoryOffset = bind.memory_offset();
    out.flags = bind.flags();
    return out;
}

}  // namespace clastrace::traces
