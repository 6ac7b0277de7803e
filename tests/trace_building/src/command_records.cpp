// SPDX-License-Identifier: Apache-2.0
#include "clastrace/trace_building/command_records.h"

#include <memory>
#include <utility>

namespace clastrace::trace_building {

fbs::BufferCreateT buffer_create(uint64_t buffer, uint64_t size, uint64_t usage) {
    fbs::BufferCreateT c;
    c.buffer = buffer;
    c.size = size;
    c.usage = usage;
    return c;
}

fbs::BufferBindMemoryT buffer_bind(uint64_t buffer, uint64_t memory, uint64_t memory_offset,
                                   uint64_t device_address) {
    fbs::BufferBindMemoryT b;
    b.buffer = buffer;
    b.memory = memory;
    b.memory_offset = memory_offset;
    b.device_address = device_address;
    return b;
}

fbs::CommandBufferBeginT command_buffer_begin(uint64_t command_buffer, uint32_t flags) {
    fbs::CommandBufferBeginT b;
    b.command_buffer = command_buffer;
    b.flags = flags;
    return b;
}

fbs::CommandBufferEndT command_buffer_end(uint64_t command_buffer) {
    fbs::CommandBufferEndT e;
    e.command_buffer = command_buffer;
    return e;
}

namespace {
std::unique_ptr<fbs::DependencyT> one_memory_barrier(uint64_t src_stages, uint64_t src_access,
                                                     uint64_t dst_stages, uint64_t dst_access) {
    auto d = std::make_unique<fbs::DependencyT>();
    d->memory_barriers.emplace_back(src_stages, src_access, dst_stages, dst_access);
    return d;
}
}  // namespace

fbs::CmdPipelineBarrierT memory_barrier(uint64_t command_buffer, uint64_t src_stages,
                                        uint64_t src_access, uint64_t dst_stages,
                                        uint64_t dst_access) {
    fbs::CmdPipelineBarrierT b;
    b.command_buffer = command_buffer;
    b.version = 2;
    b.dependency = one_memory_barrier(src_stages, src_access, dst_stages, dst_access);
    return b;
}

fbs::CmdPipelineBarrierT memory_barrier_v1(uint64_t command_buffer, uint32_t src_stages,
                                           uint32_t src_access, uint32_t dst_stages,
                                           uint32_t dst_access) {
    fbs::CmdPipelineBarrierT b;
    b.command_buffer = command_buffer;
    b.version = 1;
    b.src_stage_mask = src_stages;
    b.dst_stage_mask = dst_stages;
    b.dependency = one_memory_barrier(src_stages, src_access, dst_stages, dst_access);
    return b;
}

fbs::CmdSetEventT set_event(uint64_t command_buffer, uint64_t event, uint64_t src_stages,
                            uint64_t src_access, uint64_t dst_stages, uint64_t dst_access) {
    fbs::CmdSetEventT e;
    e.command_buffer = command_buffer;
    e.event = event;
    e.version = 2;
    e.dependency = one_memory_barrier(src_stages, src_access, dst_stages, dst_access);
    return e;
}

fbs::CmdWaitEventsT wait_event(uint64_t command_buffer, uint64_t event, uint64_t src_stages,
                               uint64_t src_access, uint64_t dst_stages, uint64_t dst_access) {
    fbs::CmdWaitEventsT w;
    w.command_buffer = command_buffer;
    w.version = 2;
    w.events.push_back(event);
    w.dependencies.push_back(one_memory_barrier(src_stages, src_access, dst_stages, dst_access));
    return w;
}

fbs::QueueSubmitT queue_submit(uint64_t queue, std::vector<uint64_t> command_buffers,
                               uint64_t fence, uint64_t submission_index) {
    fbs::QueueSubmitT s;
    s.queue = queue;
    s.version = 2;
    auto batch = std::make_unique<fbs::SubmitBatchT>();
    batch->command_buffers = std::move(command_buffers);
    s.batches.push_back(std::move(batch));
    s.fence = fence;
    s.submission_index = submission_index;
    return s;
}

fbs::FenceWaitT fence_wait(uint64_t fence) {
    fbs::FenceWaitT w;
    w.fences.push_back(fence);
    w.wait_all = true;
    return w;
}

}  // namespace clastrace::trace_building
