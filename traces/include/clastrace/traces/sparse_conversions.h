// SPDX-License-Identifier: Apache-2.0
// vkQueueBindSparse's VkBindSparseInfo <-> its trace record, written once (see
// cluster_conversions.h): buffer binds in full, image binds counted.
#pragma once

#include <clastrace/traces/trace_generated.h>
#include <clastrace/vk_cluster_abi.h>

#include <cstdint>
#include <functional>
#include <memory>
#include <span>

namespace clastrace::traces {

// One batch: its semaphores (timeline values from a chained VkTimelineSemaphoreSubmitInfo;
// 0 for binary semaphores), its buffer binds and the counts of its image binds.
// `address_of` gives a buffer's device address (0 when it has none).
std::unique_ptr<fbs::SparseBindBatchT> sparse_batch_to_record(
    const VkBindSparseInfo& info, const std::function<uint64_t(VkBuffer)>& address_of);

// A call's record: its batches in order, the fence and the result.
fbs::QueueBindSparseT queue_bind_sparse_to_record(
    VkQueue queue, std::span<const VkBindSparseInfo> infos, VkFence fence, VkResult result,
    const std::function<uint64_t(VkBuffer)>& address_of);

// VkSparseMemoryBind of a recorded bind (memory handle as recorded).
VkSparseMemoryBind sparse_bind_from_record(const fbs::SparseMemoryBind& bind);

}  // namespace clastrace::traces
