// SPDX-License-Identifier: Apache-2.0
// Record bodies that every hand-written trace repeats: buffers, command buffer begin/end,
// barriers and events with one VkMemoryBarrier2, queue submissions, fence waits. Callers set
// whatever else a test needs on the returned body before appending it.
#pragma once

#include <clastrace/traces/trace_generated.h>

#include <cstdint>
#include <vector>

namespace clastrace::trace_building {

fbs::BufferCreateT buffer_create(uint64_t buffer, uint64_t size, uint64_t usage);
fbs::BufferBindMemoryT buffer_bind(uint64_t buffer, uint64_t memory, uint64_t memory_offset,
                                   uint64_t device_address);

fbs::CommandBufferBeginT command_buffer_begin(uint64_t command_buffer, uint32_t flags = 0);
fbs::CommandBufferEndT command_buffer_end(uint64_t command_buffer);

// vkCmdPipelineBarrier2 with one VkMemoryBarrier2.
fbs::CmdPipelineBarrierT memory_barrier(uint64_t command_buffer, uint64_t src_stages,
                                        uint64_t src_access, uint64_t dst_stages,
                                        uint64_t dst_access);
// vkCmdPipelineBarrier (version 1) with one VkMemoryBarrier: the command's stage masks, also
// copied into the barrier as the capture records them.
fbs::CmdPipelineBarrierT memory_barrier_v1(uint64_t command_buffer, uint32_t src_stages,
                                           uint32_t src_access, uint32_t dst_stages,
                                           uint32_t dst_access);
// vkCmdSetEvent2 / vkCmdWaitEvents2 of one event with one VkMemoryBarrier2.
fbs::CmdSetEventT set_event(uint64_t command_buffer, uint64_t event, uint64_t src_stages,
                            uint64_t src_access, uint64_t dst_stages, uint64_t dst_access);
fbs::CmdWaitEventsT wait_event(uint64_t command_buffer, uint64_t event, uint64_t src_stages,
                               uint64_t src_access, uint64_t dst_stages, uint64_t dst_access);

// vkQueueSubmit2 of one batch (no semaphores); `submission_index` is the writer's next one.
fbs::QueueSubmitT queue_submit(uint64_t queue, std::vector<uint64_t> command_buffers,
                               uint64_t fence, uint64_t submission_index);
// vkWaitForFences of one fence, waitAll.
fbs::FenceWaitT fence_wait(uint64_t fence);

}  // namespace clastrace::trace_building
