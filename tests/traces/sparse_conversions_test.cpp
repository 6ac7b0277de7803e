// SPDX-License-Identifier: Apache-2.0
// vkQueueBindSparse -> QueueBindSparse record (traces/sparse_conversions.h), as the capture layer
// encodes each call: every batch in order with its semaphores (timeline values where chained),
// every buffer bind with the buffer's address, binds with memoryOffset and unbinds (memory
// VK_NULL_HANDLE) kept as they were, image binds counted only; the fence and the result. Read
// back through the bytes a trace stores.
#include <clastrace/traces/sparse_conversions.h>

#include <gtest/gtest.h>

#include <cstdint>
#include <type_traits>
#include <vector>

namespace clastrace::traces {
namespace {

template <class Handle>
Handle handle(uint64_t value) {
    if constexpr (std::is_pointer_v<Handle>)
        return reinterpret_cast<Handle>(uintptr_t(value));
    else
        return Handle(value);
}

const fbs::QueueBindSparse& packed(const fbs::QueueBindSparseT& record,
                                   flatbuffers::FlatBufferBuilder& fbb) {
    fbb.Finish(fbs::QueueBindSparse::Pack(fbb, &record));
    return *flatbuffers::GetRoot<fbs::QueueBindSparse>(fbb.GetBufferPointer());
}

TEST(SparseConversions, EveryBatchBindSemaphoreAndTheFenceAreRecorded) {
    // Batch 0: binary semaphores, two buffers (three binds under the first: a plain one, one
    // at a memory offset, an unbind), image binds. Batch 1: timeline values, no binds.
    const std::vector<VkSparseMemoryBind> first_binds = {
        {0, 0x10000, handle<VkDeviceMemory>(0x1001), 0, 0},
        {0x10000, 0x10000, handle<VkDeviceMemory>(0x1002), 0x30000,
         VK_SPARSE_MEMORY_BIND_METADATA_BIT},
        {0x20000, 0x10000, VK_NULL_HANDLE, 0, 0},
    };
    const std::vector<VkSparseMemoryBind> second_binds = {
        {0x4000, 0x1000, handle<VkDeviceMemory>(0x1003), 0x8000, 0}};
    const VkSparseBufferMemoryBindInfo buffers[2] = {
        {handle<VkBuffer>(0xd001), uint32_t(first_binds.size()), first_binds.data()},
        {handle<VkBuffer>(0xd002), uint32_t(second_binds.size()), second_binds.data()}};
    const VkSemaphore waits[1] = {handle<VkSemaphore>(0x8001)};
    const VkSemaphore signals[2] = {handle<VkSemaphore>(0x8002), handle<VkSemaphore>(0x8003)};
    const uint64_t signal_values[2] = {7, 9};
    VkTimelineSemaphoreSubmitInfo timeline{};
    timeline.sType = VK_STRUCTURE_TYPE_TIMELINE_SEMAPHORE_SUBMIT_INFO;
    timeline.signalSemaphoreValueCount = 2;
    timeline.pSignalSemaphoreValues = signal_values;

    VkBindSparseInfo infos[2] = {};
    infos[0].sType = infos[1].sType = VK_STRUCTURE_TYPE_BIND_SPARSE_INFO;
    infos[0].waitSemaphoreCount = 1;
    infos[0].pWaitSemaphores = waits;
    infos[0].bufferBindCount = 2;
    infos[0].pBufferBinds = buffers;
    infos[0].imageOpaqueBindCount = 2;  // counted, not followed (their pointers are not read)
    infos[0].imageBindCount = 1;
    infos[1].pNext = &timeline;
    infos[1].signalSemaphoreCount = 2;
    infos[1].pSignalSemaphores = signals;

    const fbs::QueueBindSparseT record =
        queue_bind_sparse_to_record(handle<VkQueue>(0x7001), infos, handle<VkFence>(0x9001),
                                    VK_SUCCESS, [](VkBuffer b) {
                                        return b == handle<VkBuffer>(0xd001) ? uint64_t(0x50000000)
                                                                             : 0;
                                    });
    flatbuffers::FlatBufferBuilder fbb;
    const fbs::QueueBindSparse& r = packed(record, fbb);

    EXPECT_EQ(r.queue(), 0x7001u);
    EXPECT_EQ(r.fence(), 0x9001u);
    EXPECT_EQ(r.result(), VK_SUCCESS);
    ASSERT_EQ(r.batches()->size(), 2u);
    const fbs::SparseBindBatch& b0 = *r.batches()->Get(0);
    ASSERT_EQ(b0.wait_semaphores()->size(), 1u);
    EXPECT_EQ(b0.wait_semaphores()->Get(0)->semaphore(), 0x8001u);
    EXPECT_EQ(b0.wait_semaphores()->Get(0)->value(), 0u);  // binary
    EXPECT_EQ(b0.signal_semaphores(), nullptr);            // empty vectors are not stored
    EXPECT_EQ(b0.image_opaque_bind_count(), 2u);
    EXPECT_EQ(b0.image_bind_count(), 1u);
    ASSERT_EQ(b0.buffer_binds()->size(), 2u);
    const fbs::SparseBufferBind& first = *b0.buffer_binds()->Get(0);
    EXPECT_EQ(first.buffer(), 0xd001u);
    EXPECT_EQ(first.device_address(), 0x50000000u);
    ASSERT_EQ(first.binds()->size(), 3u);
    for (uint32_t k = 0; k < 3; ++k) {
        const VkSparseMemoryBind back = sparse_bind_from_record(*first.binds()->Get(k));
        EXPECT_EQ(back.resourceOffset, first_binds[k].resourceOffset) << k;
        EXPECT_EQ(back.size, first_binds[k].size) << k;
        EXPECT_EQ(back.memory, first_binds[k].memory) << k;
        EXPECT_EQ(back.memoryOffset, first_binds[k].memoryOffset) << k;
        EXPECT_EQ(back.flags, first_binds[k].flags) << k;
    }
    EXPECT_EQ(first.binds()->Get(2)->memory(), 0u);  // the unbind
    const fbs::SparseBufferBind& second = *b0.buffer_binds()->Get(1);
    EXPECT_EQ(second.buffer(), 0xd002u);
    EXPECT_EQ(second.device_address(), 0u);
    ASSERT_EQ(second.binds()->size(), 1u);
    EXPECT_EQ(second.binds()->Get(0)->memory_offset(), 0x8000u);

    const fbs::SparseBindBatch& b1 = *r.batches()->Get(1);
    EXPECT_EQ(b1.buffer_binds(), nullptr);
    ASSERT_EQ(b1.signal_semaphores()->size(), 2u);
    EXPECT_EQ(b1.signal_semaphores()->Get(0)->semaphore(), 0x8002u);
    EXPECT_EQ(b1.signal_semaphores()->Get(0)->value(), 7u);
    EXPECT_EQ(b1.signal_semaphores()->Get(1)->value(), 9u);
}

}  // namespace
}  // namespace clastrace::traces
