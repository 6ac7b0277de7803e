// SPDX-License-Identifier: Apache-2.0
// Command recording: each intercepted command is forwarded, then recorded into the command
// buffer's log. Cluster builds get the pause points described in pause_worker.h.
#include "clastrace/capture/served_build.h"
#include "command_buffer_log.h"
#include "layer_state.h"

#include <atomic>
#include <optional>

#include <cstring>
#include <map>

namespace clastrace::capture {
namespace {

DeviceState& device_of(VkCommandBuffer cb) { return *find_device(dispatch_key(cb)); }

std::shared_ptr<CommandBufferLog> log_of(DeviceState& d, VkCommandBuffer cb) {
    std::lock_guard lock(d.command_buffers_mutex);
    auto& log = d.command_buffers[cb];
    if (!log) {
        log = std::make_shared<CommandBufferLog>();
        log->recorded.command_buffer = handle_id(cb);
    }
    return log;
}

void record(VkCommandBuffer cb, RecordedCommand command) {
    DeviceState& d = device_of(cb);
    if (!d.sink) return;
    log_of(d, cb)->recorded.commands.push_back(std::move(command));
}

// ---- Lifetime ---------------------------------------------------------------------------

VKAPI_ATTR VkResult VKAPI_CALL BeginCommandBuffer(VkCommandBuffer cb,
                                                  const VkCommandBufferBeginInfo* p_begin_info) {
    DeviceState& d = device_of(cb);
    auto log = log_of(d, cb);
    clear_command_buffer_log(d, *log);  // begin implicitly resets
    log->recorded.usage = p_begin_info->flags;
    {
        std::lock_guard lock(d.command_buffers_mutex);
        log->recorded.secondary = d.secondary_command_buffers.count(cb) != 0;
    }
    return d.next.BeginCommandBuffer(cb, p_begin_info);
}

VKAPI_ATTR VkResult VKAPI_CALL EndCommandBuffer(VkCommandBuffer cb) {
    DeviceState& d = device_of(cb);
    VkResult result = d.next.EndCommandBuffer(cb);
    if (result == VK_SUCCESS && d.sink) d.sink->command_buffer_recorded(log_of(d, cb)->recorded);
    return result;
}

VKAPI_ATTR VkResult VKAPI_CALL ResetCommandBuffer(VkCommandBuffer cb,
                                                  VkCommandBufferResetFlags flags) {
    DeviceState& d = device_of(cb);
    VkResult result = d.next.ResetCommandBuffer(cb, flags);
    if (result == VK_SUCCESS) {
        clear_command_buffer_log(d, *log_of(d, cb));
        if (d.sink) d.sink->command_buffer_reset(handle_id(cb));
    }
    return result;
}

VKAPI_ATTR VkResult VKAPI_CALL AllocateCommandBuffers(VkDevice device,
                                                      const VkCommandBufferAllocateInfo* p_info,
                                                      VkCommandBuffer* p_command_buffers) {
    DeviceState& d = *find_device(dispatch_key(device));
    VkResult result = d.next.AllocateCommandBuffers(device, p_info, p_command_buffers);
    if (result != VK_SUCCESS) return result;
    std::lock_guard lock(d.command_buffers_mutex);
    auto& owned = d.pool_command_buffers[p_info->commandPool];
    owned.insert(owned.end(), p_command_buffers, p_command_buffers + p_info->commandBufferCount);
    if (p_info->level == VK_COMMAND_BUFFER_LEVEL_SECONDARY)
        d.secondary_command_buffers.insert(p_command_buffers,
                                           p_command_buffers + p_info->commandBufferCount);
    return result;
}

void forget_command_buffers(DeviceState& d, VkCommandPool pool, const VkCommandBuffer* list,
                            uint32_t count) {
    std::lock_guard lock(d.command_buffers_mutex);
    for (uint32_t i = 0; i < count; ++i) {
        if (!list[i]) continue;
        auto it = d.command_buffers.find(list[i]);
        if (it != d.command_buffers.end()) {
            release_command_buffer_log(d, *it->second);
            d.command_buffers.erase(it);
        }
        d.secondary_command_buffers.erase(list[i]);
        auto& owned = d.pool_command_buffers[pool];
        owned.erase(std::remove(owned.begin(), owned.end(), list[i]), owned.end());
    }
}

VKAPI_ATTR void VKAPI_CALL FreeCommandBuffers(VkDevice device, VkCommandPool pool, uint32_t count,
                                              const VkCommandBuffer* p_command_buffers) {
    DeviceState& d = *find_device(dispatch_key(device));
    forget_command_buffers(d, pool, p_command_buffers, count);
    d.next.FreeCommandBuffers(device, pool, count, p_command_buffers);
}

VKAPI_ATTR VkResult VKAPI_CALL ResetCommandPool(VkDevice device, VkCommandPool pool,
                                                VkCommandPoolResetFlags flags) {
    DeviceState& d = *find_device(dispatch_key(device));
    VkResult result = d.next.ResetCommandPool(device, pool, flags);
    if (result != VK_SUCCESS) return result;
    std::lock_guard lock(d.command_buffers_mutex);
    for (VkCommandBuffer cb : d.pool_command_buffers[pool]) {
        auto it = d.command_buffers.find(cb);
        if (it == d.command_buffers.end()) continue;
        clear_command_buffer_log(d, *it->second);
        if (d.sink) d.sink->command_buffer_reset(handle_id(cb));
    }
    return result;
}

VKAPI_ATTR void VKAPI_CALL DestroyCommandPool(VkDevice device, VkCommandPool pool,
                                              const VkAllocationCallbacks* p_allocator) {
    DeviceState& d = *find_device(dispatch_key(device));
    std::vector<VkCommandBuffer> owned;
    {
        std::lock_guard lock(d.command_buffers_mutex);
        owned = d.pool_command_buffers[pool];
    }
    forget_command_buffers(d, pool, owned.data(), uint32_t(owned.size()));
    {
        std::lock_guard lock(d.command_buffers_mutex);
        d.pool_command_buffers.erase(pool);
    }
    d.next.DestroyCommandPool(device, pool, p_allocator);
}

// ---- Synchronization --------------------------------------------------------------------

void copy_barriers1(uint64_t src_stage, uint64_t dst_stage, uint32_t memory_count,
                    const VkMemoryBarrier* memory, uint32_t buffer_count,
                    const VkBufferMemoryBarrier* buffers, std::vector<MemoryBarrier>& out_memory,
                    std::vector<BufferBarrier>& out_buffers) {
    for (uint32_t i = 0; i < memory_count; ++i)
        out_memory.push_back(
            {src_stage, memory[i].srcAccessMask, dst_stage, memory[i].dstAccessMask});
    for (uint32_t i = 0; i < buffer_count; ++i)
        out_buffers.push_back({src_stage, buffers[i].srcAccessMask, dst_stage,
                               buffers[i].dstAccessMask, handle_id(buffers[i].buffer),
                               buffers[i].offset, buffers[i].size});
}

void copy_dependency(const VkDependencyInfo& info, std::vector<MemoryBarrier>& out_memory,
                     std::vector<BufferBarrier>& out_buffers, uint32_t& image_count) {
    for (uint32_t i = 0; i < info.memoryBarrierCount; ++i) {
        const auto& b = info.pMemoryBarriers[i];
        out_memory.push_back({b.srcStageMask, b.srcAccessMask, b.dstStageMask, b.dstAccessMask});
    }
    for (uint32_t i = 0; i < info.bufferMemoryBarrierCount; ++i) {
        const auto& b = info.pBufferMemoryBarriers[i];
        out_buffers.push_back({b.srcStageMask, b.srcAccessMask, b.dstStageMask, b.dstAccessMask,
                               handle_id(b.buffer), b.offset, b.size});
    }
    image_count += info.imageMemoryBarrierCount;
}

VKAPI_ATTR void VKAPI_CALL CmdPipelineBarrier(
    VkCommandBuffer cb, VkPipelineStageFlags src_stage_mask, VkPipelineStageFlags dst_stage_mask,
    VkDependencyFlags dependency_flags, uint32_t memory_barrier_count,
    const VkMemoryBarrier* p_memory_barriers, uint32_t buffer_memory_barrier_count,
    const VkBufferMemoryBarrier* p_buffer_memory_barriers, uint32_t image_memory_barrier_count,
    const VkImageMemoryBarrier* p_image_memory_barriers) {
    device_of(cb).next.CmdPipelineBarrier(cb, src_stage_mask, dst_stage_mask, dependency_flags,
                                          memory_barrier_count, p_memory_barriers,
                                          buffer_memory_barrier_count, p_buffer_memory_barriers,
                                          image_memory_barrier_count, p_image_memory_barriers);
    BarrierCommand c;
    c.src_stage_mask = src_stage_mask;
    c.dst_stage_mask = dst_stage_mask;
    c.dependency_flags = dependency_flags;
    copy_barriers1(src_stage_mask, dst_stage_mask, memory_barrier_count, p_memory_barriers,
                   buffer_memory_barrier_count, p_buffer_memory_barriers, c.memory_barriers,
                   c.buffer_barriers);
    c.image_barrier_count = image_memory_barrier_count;
    record(cb, std::move(c));
}

void pipeline_barrier2(VkCommandBuffer cb, const VkDependencyInfo* info,
                       PFN_vkCmdPipelineBarrier2 next) {
    next(cb, info);
    BarrierCommand c;
    c.synchronization2 = true;
    c.dependency_flags = info->dependencyFlags;
    copy_dependency(*info, c.memory_barriers, c.buffer_barriers, c.image_barrier_count);
    record(cb, std::move(c));
}
VKAPI_ATTR void VKAPI_CALL CmdPipelineBarrier2(VkCommandBuffer cb, const VkDependencyInfo* info) {
    pipeline_barrier2(cb, info, device_of(cb).next.CmdPipelineBarrier2);
}
VKAPI_ATTR void VKAPI_CALL CmdPipelineBarrier2KHR(VkCommandBuffer cb,
                                                  const VkDependencyInfo* info) {
    pipeline_barrier2(cb, info, device_of(cb).next.CmdPipelineBarrier2KHR);
}

VKAPI_ATTR void VKAPI_CALL CmdSetEvent(VkCommandBuffer cb, VkEvent event,
                                       VkPipelineStageFlags stage_mask) {
    device_of(cb).next.CmdSetEvent(cb, event, stage_mask);
    EventCommand c;
    c.kind = EventCommand::Kind::kSet;
    c.events = {handle_id(event)};
    c.src_stage_mask = stage_mask;
    record(cb, std::move(c));
}
VKAPI_ATTR void VKAPI_CALL CmdResetEvent(VkCommandBuffer cb, VkEvent event,
                                         VkPipelineStageFlags stage_mask) {
    device_of(cb).next.CmdResetEvent(cb, event, stage_mask);
    EventCommand c;
    c.kind = EventCommand::Kind::kReset;
    c.events = {handle_id(event)};
    c.src_stage_mask = stage_mask;
    record(cb, std::move(c));
}
VKAPI_ATTR void VKAPI_CALL CmdWaitEvents(
    VkCommandBuffer cb, uint32_t event_count, const VkEvent* p_events,
    VkPipelineStageFlags src_stage_mask, VkPipelineStageFlags dst_stage_mask,
    uint32_t memory_barrier_count, const VkMemoryBarrier* p_memory_barriers,
    uint32_t buffer_memory_barrier_count, const VkBufferMemoryBarrier* p_buffer_memory_barriers,
    uint32_t image_memory_barrier_count, const VkImageMemoryBarrier* p_image_memory_barriers) {
    device_of(cb).next.CmdWaitEvents(cb, event_count, p_events, src_stage_mask, dst_stage_mask,
                                     memory_barrier_count, p_memory_barriers,
                                     buffer_memory_barrier_count, p_buffer_memory_barriers,
                                     image_memory_barrier_count, p_image_memory_barriers);
    EventCommand c;
    c.kind = EventCommand::Kind::kWait;
    for (uint32_t i = 0; i < event_count; ++i) c.events.push_back(handle_id(p_events[i]));
    c.src_stage_mask = src_stage_mask;
    c.dst_stage_mask = dst_stage_mask;
    copy_barriers1(src_stage_mask, dst_stage_mask, memory_barrier_count, p_memory_barriers,
                   buffer_memory_barrier_count, p_buffer_memory_barriers, c.memory_barriers,
                   c.buffer_barriers);
    record(cb, std::move(c));
}

void set_event2(VkCommandBuffer cb, VkEvent event, const VkDependencyInfo* info,
                PFN_vkCmdSetEvent2 next) {
    next(cb, event, info);
    EventCommand c;
    c.kind = EventCommand::Kind::kSet;
    c.synchronization2 = true;
    c.events = {handle_id(event)};
    uint32_t images = 0;
    copy_dependency(*info, c.memory_barriers, c.buffer_barriers, images);
    record(cb, std::move(c));
}
VKAPI_ATTR void VKAPI_CALL CmdSetEvent2(VkCommandBuffer cb, VkEvent e, const VkDependencyInfo* i) {
    set_event2(cb, e, i, device_of(cb).next.CmdSetEvent2);
}
VKAPI_ATTR void VKAPI_CALL CmdSetEvent2KHR(VkCommandBuffer cb, VkEvent e,
                                           const VkDependencyInfo* i) {
    set_event2(cb, e, i, device_of(cb).next.CmdSetEvent2KHR);
}
void reset_event2(VkCommandBuffer cb, VkEvent event, VkPipelineStageFlags2 stage_mask,
                  PFN_vkCmdResetEvent2 next) {
    next(cb, event, stage_mask);
    EventCommand c;
    c.kind = EventCommand::Kind::kReset;
    c.synchronization2 = true;
    c.events = {handle_id(event)};
    c.src_stage_mask = stage_mask;
    record(cb, std::move(c));
}
VKAPI_ATTR void VKAPI_CALL CmdResetEvent2(VkCommandBuffer cb, VkEvent e, VkPipelineStageFlags2 s) {
    reset_event2(cb, e, s, device_of(cb).next.CmdResetEvent2);
}
VKAPI_ATTR void VKAPI_CALL CmdResetEvent2KHR(VkCommandBuffer cb, VkEvent e,
                                             VkPipelineStageFlags2 s) {
    reset_event2(cb, e, s, device_of(cb).next.CmdResetEvent2KHR);
}
void wait_events2(VkCommandBuffer cb, uint32_t count, const VkEvent* events,
                  const VkDependencyInfo* infos, PFN_vkCmdWaitEvents2 next) {
    next(cb, count, events, infos);
    EventCommand c;
    c.kind = EventCommand::Kind::kWait;
    c.synchronization2 = true;
    uint32_t images = 0;
    for (uint32_t i = 0; i < count; ++i) {
        c.events.push_back(handle_id(events[i]));
        copy_dependency(infos[i], c.memory_barriers, c.buffer_barriers, images);
    }
    record(cb, std::move(c));
}
VKAPI_ATTR void VKAPI_CALL CmdWaitEvents2(VkCommandBuffer cb, uint32_t n, const VkEvent* e,
                                          const VkDependencyInfo* i) {
    wait_events2(cb, n, e, i, device_of(cb).next.CmdWaitEvents2);
}
VKAPI_ATTR void VKAPI_CALL CmdWaitEvents2KHR(VkCommandBuffer cb, uint32_t n, const VkEvent* e,
                                             const VkDependencyInfo* i) {
    wait_events2(cb, n, e, i, device_of(cb).next.CmdWaitEvents2KHR);
}

// ---- Transfers and dispatches ---------------------------------------------------------------

VKAPI_ATTR void VKAPI_CALL CmdCopyBuffer(VkCommandBuffer cb, VkBuffer src, VkBuffer dst,
                                         uint32_t region_count, const VkBufferCopy* p_regions) {
    device_of(cb).next.CmdCopyBuffer(cb, src, dst, region_count, p_regions);
    record(cb, CopyBufferCommand{handle_id(src),
                                 handle_id(dst),
                                 {p_regions, p_regions + region_count}});
}
void copy_buffer2(VkCommandBuffer cb, const VkCopyBufferInfo2* info, PFN_vkCmdCopyBuffer2 next) {
    next(cb, info);
    CopyBufferCommand c{handle_id(info->srcBuffer), handle_id(info->dstBuffer), {}};
    for (uint32_t i = 0; i < info->regionCount; ++i)
        c.regions.push_back(
            {info->pRegions[i].srcOffset, info->pRegions[i].dstOffset, info->pRegions[i].size});
    record(cb, std::move(c));
}
VKAPI_ATTR void VKAPI_CALL CmdCopyBuffer2(VkCommandBuffer cb, const VkCopyBufferInfo2* info) {
    copy_buffer2(cb, info, device_of(cb).next.CmdCopyBuffer2);
}
VKAPI_ATTR void VKAPI_CALL CmdCopyBuffer2KHR(VkCommandBuffer cb, const VkCopyBufferInfo2* info) {
    copy_buffer2(cb, info, device_of(cb).next.CmdCopyBuffer2KHR);
}
VKAPI_ATTR void VKAPI_CALL CmdFillBuffer(VkCommandBuffer cb, VkBuffer dst, VkDeviceSize offset,
                                         VkDeviceSize size, uint32_t data) {
    device_of(cb).next.CmdFillBuffer(cb, dst, offset, size, data);
    record(cb, FillBufferCommand{handle_id(dst), offset, size, data});
}
VKAPI_ATTR void VKAPI_CALL CmdUpdateBuffer(VkCommandBuffer cb, VkBuffer dst, VkDeviceSize offset,
                                           VkDeviceSize size, const void* p_data) {
    device_of(cb).next.CmdUpdateBuffer(cb, dst, offset, size, p_data);
    auto* bytes = static_cast<const uint8_t*>(p_data);
    record(cb, UpdateBufferCommand{handle_id(dst), offset, {bytes, bytes + size}});
}

// ---- Binding state: the storage buffers a dispatch sees, the structures a consumer reaches ---

}  // namespace

std::shared_ptr<CommandBufferLog> command_buffer_log_of(DeviceState& d, VkCommandBuffer cb) {
    return log_of(d, cb);
}

namespace {

bool is_buffer_descriptor(VkDescriptorType type) {
    return type == VK_DESCRIPTOR_TYPE_STORAGE_BUFFER ||
           type == VK_DESCRIPTOR_TYPE_STORAGE_BUFFER_DYNAMIC ||
           type == VK_DESCRIPTOR_TYPE_UNIFORM_BUFFER ||
           type == VK_DESCRIPTOR_TYPE_UNIFORM_BUFFER_DYNAMIC;
}

bool is_dynamic_buffer(VkDescriptorType type) {
    return type == VK_DESCRIPTOR_TYPE_STORAGE_BUFFER_DYNAMIC ||
           type == VK_DESCRIPTOR_TYPE_UNIFORM_BUFFER_DYNAMIC;
}

bool is_uniform_buffer(VkDescriptorType type) {
    return type == VK_DESCRIPTOR_TYPE_UNIFORM_BUFFER ||
           type == VK_DESCRIPTOR_TYPE_UNIFORM_BUFFER_DYNAMIC;
}

}  // namespace

// Storage and uniform buffers are both kept: dispatches and rays record the storage ones
// (bound_storage_buffers), consumers that load structure addresses search both
// (bound_address_buffers).
void track_descriptor_write(DeviceState& d, const VkWriteDescriptorSet& write) {
    std::lock_guard lock(d.descriptors_mutex);
    const bool buffer = is_buffer_descriptor(write.descriptorType);
    auto& set = d.descriptors[write.dstSet];
    if (track_acceleration_structure_write(d, write, set)) return;
    // Consecutive descriptors continue at element + i of the same binding (overflow into the
    // next binding is not followed).
    for (uint32_t i = 0; i < write.descriptorCount; ++i) {
        const std::pair<uint32_t, uint32_t> key{write.dstBinding, write.dstArrayElement + i};
        if (!buffer || !write.pBufferInfo) {
            set.erase(key);
            continue;
        }
        const VkDescriptorBufferInfo& info = write.pBufferInfo[i];
        BoundStorageBuffer b;
        b.binding = write.dstBinding;
        b.array_element = write.dstArrayElement + i;
        b.type = write.descriptorType;
        b.buffer = handle_id(info.buffer);
        b.offset = info.offset;
        b.range = info.range;
        set[key] = b;
    }
}

namespace {

VKAPI_ATTR void VKAPI_CALL UpdateDescriptorSets(VkDevice device, uint32_t write_count,
                                                const VkWriteDescriptorSet* writes,
                                                uint32_t copy_count,
                                                const VkCopyDescriptorSet* copies) {
    DeviceState& d = *find_device(dispatch_key(device));
    d.next.UpdateDescriptorSets(device, write_count, writes, copy_count, copies);
    for (uint32_t w = 0; w < write_count; ++w) track_descriptor_write(d, writes[w]);
    std::lock_guard lock(d.descriptors_mutex);
    for (uint32_t c = 0; c < copy_count; ++c) {
        const VkCopyDescriptorSet& copy = copies[c];
        auto source = d.descriptors.find(copy.srcSet);
        for (uint32_t i = 0; i < copy.descriptorCount; ++i) {
            const std::pair<uint32_t, uint32_t> to{copy.dstBinding, copy.dstArrayElement + i};
            auto& dst = d.descriptors[copy.dstSet];
            if (source == d.descriptors.end()) {
                dst.erase(to);
                continue;
            }
            auto from = source->second.find({copy.srcBinding, copy.srcArrayElement + i});
            if (from == source->second.end()) {
                dst.erase(to);
                continue;
            }
            TrackedDescriptor copied = from->second;
            std::visit(
                [&](auto& descriptor) {
                    descriptor.binding = to.first;
                    descriptor.array_element = to.second;
                },
                copied);
            dst[to] = copied;
        }
    }
}

VKAPI_ATTR void VKAPI_CALL CmdBindPipeline(VkCommandBuffer cb, VkPipelineBindPoint bind_point,
                                           VkPipeline pipeline) {
    DeviceState& d = device_of(cb);
    d.next.CmdBindPipeline(cb, bind_point, pipeline);
    if (bind_point == VK_PIPELINE_BIND_POINT_COMPUTE)
        log_of(d, cb)->compute_pipeline = handle_id(pipeline);
    else if (bind_point == VK_PIPELINE_BIND_POINT_GRAPHICS)
        log_of(d, cb)->graphics_pipeline = handle_id(pipeline);
    else if (bind_point == VK_PIPELINE_BIND_POINT_RAY_TRACING_KHR)
        log_of(d, cb)->ray_tracing_pipeline = handle_id(pipeline);
}

VKAPI_ATTR void VKAPI_CALL CmdBindDescriptorSets(VkCommandBuffer cb, VkPipelineBindPoint bind_point,
                                                 VkPipelineLayout layout, uint32_t first_set,
                                                 uint32_t set_count, const VkDescriptorSet* sets,
                                                 uint32_t dynamic_offset_count,
                                                 const uint32_t* dynamic_offsets) {
    DeviceState& d = device_of(cb);
    d.next.CmdBindDescriptorSets(cb, bind_point, layout, first_set, set_count, sets,
                                 dynamic_offset_count, dynamic_offsets);
    auto log = log_of(d, cb);
    CommandBufferLog::BoundSets* bound_sets = log->sets_at(bind_point);
    if (!bound_sets) return;
    log->forget_pushed_sets(bind_point_index(bind_point), first_set, set_count);
    // Dynamic offsets are consumed set by set, in binding order, by every dynamic descriptor
    // (storage and uniform buffers, both tracked).
    uint32_t next_offset = 0;
    std::lock_guard lock(d.descriptors_mutex);
    for (uint32_t s = 0; s < set_count; ++s) {
        std::vector<uint32_t> offsets;
        auto known = d.descriptors.find(sets[s]);
        if (known != d.descriptors.end())
            for (const auto& [key, descriptor] : known->second) {
                const auto* b = std::get_if<BoundStorageBuffer>(&descriptor);
                if (b && is_dynamic_buffer(b->type) && next_offset < dynamic_offset_count)
                    offsets.push_back(dynamic_offsets[next_offset++]);
            }
        (*bound_sets)[first_set + s] = {sets[s], offsets};
    }
}

}  // namespace

namespace {

// The buffer descriptors of the bound `sets`, uniform ones only `with_uniform`.
std::vector<BoundStorageBuffer> bound_buffers(DeviceState& d,
                                              const CommandBufferLog::BoundSets& sets,
                                              bool with_uniform) {
    std::vector<BoundStorageBuffer> out;
    std::lock_guard lock(d.descriptors_mutex);
    for (const auto& [setIndex, bound] : sets) {
        auto known = d.descriptors.find(bound.first);
        if (known == d.descriptors.end()) continue;
        size_t dynamic = 0;
        for (const auto& [key, tracked] : known->second) {
            const auto* storage = std::get_if<BoundStorageBuffer>(&tracked);
            if (!storage) continue;
            BoundStorageBuffer b = *storage;
            b.set = setIndex;
            // Every dynamic descriptor takes its offset, whether it is returned or not.
            if (is_dynamic_buffer(b.type) && dynamic < bound.second.size())
                b.offset += bound.second[dynamic++];
            if (is_uniform_buffer(b.type) && !with_uniform) continue;
            if (auto buffer = d.memory_map.buffer(b.buffer); buffer && buffer->address)
                b.address = buffer->address + b.offset;
            out.push_back(b);
        }
    }
    return out;
}

}  // namespace

std::vector<BoundStorageBuffer> bound_storage_buffers(DeviceState& d,
                                                      const CommandBufferLog::BoundSets& sets) {
    return bound_buffers(d, sets, false);
}

std::vector<BoundStorageBuffer> bound_address_buffers(DeviceState& d,
                                                      const CommandBufferLog::BoundSets& sets) {
    return bound_buffers(d, sets, true);
}

namespace {

void record_pause(DeviceState& d, VkCommandBuffer cb, CommandBufferLog& log, PausePoint pause);

// CLASTRACE_DEVICE_ADDRESS_WRITES=exact: a dispatch that may write through device addresses gets
// a pause before and after it, where the worker compares memory (exact_address_writes.h).
// Returns the pause id that links the dispatch to its captures (0: no pauses).
uint64_t pause_before_address_writer(DeviceState& d, VkCommandBuffer cb, CommandBufferLog& log,
                                     bool marked) {
    if (!marked || !layer_config().exact_device_address_writes || !d.capturing_now()) return 0;
    PausePoint before;
    before.pause_id = ++d.pause_counter;
    before.phase = PausePhase::kBeforeCommand;
    before.last_of_command = false;
    before.address_writes = true;
    record_pause(d, cb, log, before);
    return before.pause_id;
}
void pause_after_address_writer(DeviceState& d, VkCommandBuffer cb, CommandBufferLog& log,
                                uint64_t pause_id) {
    if (!pause_id) return;
    PausePoint after;
    after.pause_id = pause_id;
    after.phase = PausePhase::kAfterCommand;
    after.address_writes = true;
    record_pause(d, cb, log, after);
}

// A dispatch of the bound compute pipeline: the storage buffers it sees, whether its shader may
// write through addresses or uses ray queries, and the structures it then reaches.
DispatchCommand dispatch_command(DeviceState& d, const CommandBufferLog& log) {
    DispatchCommand c;
    c.pipeline = log.compute_pipeline;
    c.storage_buffers = bound_storage_buffers(d, log.compute_sets);
    c.may_write_device_addresses = address_writing_stages(d, log.compute_pipeline) != 0;
    c.ray_query = ray_query_stages(d, log.compute_pipeline) != 0;
    if (c.ray_query)
        c.acceleration_structures =
            reachable_acceleration_structures(d, log, VK_PIPELINE_BIND_POINT_COMPUTE);
    return c;
}

VKAPI_ATTR void VKAPI_CALL CmdDispatch(VkCommandBuffer cb, uint32_t x, uint32_t y, uint32_t z) {
    DeviceState& d = device_of(cb);
    if (!d.sink) return d.next.CmdDispatch(cb, x, y, z);
    auto log = log_of(d, cb);
    DispatchCommand c = dispatch_command(d, *log);
    c.group_count_x = x;
    c.group_count_y = y;
    c.group_count_z = z;
    c.pause_id = pause_before_address_writer(d, cb, *log, c.may_write_device_addresses);
    d.next.CmdDispatch(cb, x, y, z);
    pause_after_address_writer(d, cb, *log, c.pause_id);
    log->recorded.commands.push_back(std::move(c));
}

VKAPI_ATTR void VKAPI_CALL CmdDispatchIndirect(VkCommandBuffer cb, VkBuffer buffer,
                                               VkDeviceSize offset) {
    DeviceState& d = device_of(cb);
    if (!d.sink) return d.next.CmdDispatchIndirect(cb, buffer, offset);
    auto log = log_of(d, cb);
    DispatchCommand c = dispatch_command(d, *log);
    c.indirect_buffer = handle_id(buffer);
    c.indirect_offset = offset;
    c.pause_id = pause_before_address_writer(d, cb, *log, c.may_write_device_addresses);
    d.next.CmdDispatchIndirect(cb, buffer, offset);
    pause_after_address_writer(d, cb, *log, c.pause_id);
    log->recorded.commands.push_back(std::move(c));
}

}  // namespace

// Only draws that may write through addresses or use ray queries are recorded: replay needs
// nothing else of them.
void record_draw_through_addresses(VkCommandBuffer cb, const char* entry_point) {
    DeviceState& d = device_of(cb);
    if (!d.sink) return;
    auto log = log_of(d, cb);
    const VkPipelineStageFlags2 stages = address_writing_stages(d, log->graphics_pipeline);
    const VkPipelineStageFlags2 ray_stages = ray_query_stages(d, log->graphics_pipeline);
    if (!stages && !ray_stages) return;
    // Exact mode pauses around dispatches only: a pause cannot stop the queue inside a render
    // pass, so a draw stays a possible writer of all device-address memory (capture/README.md).
    static std::atomic<bool> said_draws_stay_cheap{false};
    if (stages && layer_config().exact_device_address_writes &&
        !said_draws_stay_cheap.exchange(true))
        log_message(LogLevel::kInfo,
                    "CLASTRACE_DEVICE_ADDRESS_WRITES=exact: draws (%s) whose shaders may write "
                    "through device addresses are recorded as in cheap mode (possible writers of "
                    "all device-address memory); only dispatches are compared",
                    entry_point);
    DrawCommand c;
    c.pipeline = log->graphics_pipeline;
    c.entry_point = entry_point;
    c.address_stages = stages;
    c.ray_query_stages = ray_stages;
    if (ray_stages)
        c.acceleration_structures =
            reachable_acceleration_structures(d, *log, VK_PIPELINE_BIND_POINT_GRAPHICS);
    log->recorded.commands.push_back(std::move(c));
}

namespace {

VKAPI_ATTR void VKAPI_CALL CmdExecuteCommands(VkCommandBuffer cb, uint32_t count,
                                              const VkCommandBuffer* secondaries) {
    DeviceState& d = device_of(cb);
    d.next.CmdExecuteCommands(cb, count, secondaries);
    // The secondaries' pauses happen when this primary runs: the worker must expect them here,
    // in execution order (a secondary listed twice pauses twice).
    auto primary = log_of(d, cb);
    ExecuteCommandsCommand c;
    for (uint32_t i = 0; i < count; ++i) {
        auto secondary = log_of(d, secondaries[i]);
        const size_t first = primary->pauses.size();
        primary->pauses.insert(primary->pauses.end(), secondary->pauses.begin(),
                               secondary->pauses.end());
        // A simultaneous-use secondary may run inside primaries on two queues at once.
        if (secondary->recorded.usage & VK_COMMAND_BUFFER_USAGE_SIMULTANEOUS_USE_BIT)
            for (size_t p = first; p < primary->pauses.size(); ++p)
                primary->pauses[p].shared = true;
        c.secondaries.push_back(handle_id(secondaries[i]));
    }
    if (d.sink) primary->recorded.commands.push_back(std::move(c));
}

// ---- The captured commands ------------------------------------------------------------------

// Records barrier + set(signal) + wait(release) + reset(release); see pause_worker.h.
void record_pause(DeviceState& d, VkCommandBuffer cb, CommandBufferLog& log, PausePoint pause) {
    VkEventCreateInfo event_info{VK_STRUCTURE_TYPE_EVENT_CREATE_INFO, nullptr, 0};
    auto event = [&](VkEvent* out) {
        if (log.spare_events.empty())
            return d.next.CreateEvent(d.device, &event_info, nullptr, out) == VK_SUCCESS;
        *out = log.spare_events.back();
        log.spare_events.pop_back();
        return true;
    };
    // Spares lie in (signal, release) pairs: each event keeps its role (validation tracks which
    // stage last set an event, and a wait names that stage).
    if (!event(&pause.release)) return;
    if (!event(&pause.signal)) {
        log.spare_events.push_back(pause.release);
        return;
    }
    log.events.push_back(pause.signal);
    log.events.push_back(pause.release);
    std::shared_ptr<StagingSet> staging = create_staging(d);
    if (staging) {
        log.staging.push_back(staging);
        pause.staging = staging;
        record_copies_to_staging(d, cb, *staging);
    }

    const VkMemoryBarrier to_host{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr,
                                  VK_ACCESS_MEMORY_WRITE_BIT,
                                  VK_ACCESS_HOST_READ_BIT | VK_ACCESS_MEMORY_READ_BIT};
    d.next.CmdPipelineBarrier(cb, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT,
                              VK_PIPELINE_STAGE_ALL_COMMANDS_BIT | VK_PIPELINE_STAGE_HOST_BIT, 0, 1,
                              &to_host, 0, nullptr, 0, nullptr);
    d.next.CmdSetEvent(cb, pause.signal, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT);
    const VkMemoryBarrier from_host{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr,
                                    VK_ACCESS_HOST_WRITE_BIT,
                                    VK_ACCESS_MEMORY_READ_BIT | VK_ACCESS_MEMORY_WRITE_BIT};
    d.next.CmdWaitEvents(cb, 1, &pause.release, VK_PIPELINE_STAGE_HOST_BIT,
                         VK_PIPELINE_STAGE_ALL_COMMANDS_BIT, 1, &from_host, 0, nullptr, 0, nullptr);
    d.next.CmdResetEvent(cb, pause.release, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT);
    // A served build wrote its outputs into the staged copies.
    if (staging && d.serving && pause.parameters && pause.phase == PausePhase::kBeforeCommand)
        record_copies_from_staging(d, cb, *staging);
    log.pauses.push_back(std::move(pause));
}

// Queries per recording: a pair per captured command. Commands past the first 128 of one
// recording get no timestamps (the analyzer simply sees no span for them).
constexpr uint32_t kTimestampQueries = 256;

// Writes a timestamp of the layer's own pool into `cb` and returns its record (the caller puts
// it in the log around the command's record), or nothing when timestamps are off, the command
// buffer is secondary (its pauses run inside a primary; not supported), or the pool is full.
// `pairStart`: the first of a pair, written only when its partner fits too.
std::optional<TimestampWriteCommand> write_timestamp(DeviceState& d, VkCommandBuffer cb,
                                                     CommandBufferLog& log,
                                                     VkPipelineStageFlagBits stage,
                                                     bool pair_start) {
    if (!d.timestamps || !d.capturing_now() || log.recorded.secondary) return std::nullopt;
    if (log.timestamps_written + (pair_start ? 2 : 1) > kTimestampQueries) return std::nullopt;
    if (!log.timestamp_pool && log.spare_timestamp_pool) {
        log.timestamp_pool = log.spare_timestamp_pool;
        log.spare_timestamp_pool = VK_NULL_HANDLE;
        d.next.CmdResetQueryPool(cb, log.timestamp_pool, 0, kTimestampQueries);
        log.timestamp_read_pause_id = ++d.pause_counter;
    }
    if (!log.timestamp_pool) {
        VkQueryPoolCreateInfo info{};
        info.sType = VK_STRUCTURE_TYPE_QUERY_POOL_CREATE_INFO;
        info.queryType = VK_QUERY_TYPE_TIMESTAMP;
        info.queryCount = kTimestampQueries;
        if (d.next.CreateQueryPool(d.device, &info, nullptr, &log.timestamp_pool) != VK_SUCCESS) {
            log.timestamp_pool = VK_NULL_HANDLE;
            log.timestamps_written = kTimestampQueries;  // do not try again in this recording
            return std::nullopt;
        }
        // Reset in the command buffer, so each execution starts from unavailable queries.
        d.next.CmdResetQueryPool(cb, log.timestamp_pool, 0, kTimestampQueries);
        log.timestamp_read_pause_id = ++d.pause_counter;
    }
    const uint32_t query = log.timestamps_written++;
    d.next.CmdWriteTimestamp(cb, stage, log.timestamp_pool, query);
    return TimestampWriteCommand{handle_id(log.timestamp_pool), query, uint64_t(stage),
                                 log.timestamp_read_pause_id};
}

// Start: once everything before (the pause's wait included) has finished, so the span is the
// command's alone. End: once the command has finished.
std::optional<TimestampWriteCommand> timestamp_before(DeviceState& d, VkCommandBuffer cb,
                                                      CommandBufferLog& log) {
    auto t = write_timestamp(d, cb, log, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT, true);
    if (t) log.recorded.commands.push_back(*t);
    return t;
}
std::optional<TimestampWriteCommand> timestamp_after(DeviceState& d, VkCommandBuffer cb,
                                                     CommandBufferLog& log, bool started) {
    if (!started) return std::nullopt;
    return write_timestamp(d, cb, log, VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT, false);
}

VKAPI_ATTR void VKAPI_CALL CmdBuildClusterAccelerationStructureIndirectNV(
    VkCommandBuffer cb, const VkClusterAccelerationStructureCommandsInfoNV* p_command_infos) {
    DeviceState& d = device_of(cb);
    auto parameters = std::make_shared<const ClusterCommandParameters>(
        ClusterCommandParameters::copy_of(*p_command_infos));
    const uint64_t pause_id = ++d.pause_counter;
    auto log = log_of(d, cb);
    // Capture needs a pause before (inputs) and after (outputs); serving needs the one before,
    // where the build runs while the queue waits.
    // When serving, the command is the engine's run at the pause before it, and the queue does
    // nothing until the next command: the outputs are read in that same pause.
    const bool pause_after = d.capturing_now() && !d.serving;
    // Served, the command's execution is the engine's run inside the pause before it: its span
    // covers that pause (the queue's time on the command, capture reading included). Native, the
    // span starts after the pause, so the capture's stall is not counted.
    bool started = d.serving && timestamp_before(d, cb, *log).has_value();
    if (d.capturing_now() || d.serving) {
        PausePoint before;
        before.pause_id = pause_id;
        before.phase = PausePhase::kBeforeCommand;
        before.last_of_command = !pause_after;
        before.parameters = parameters;
        record_pause(d, cb, *log, before);
    }
    if (!d.serving) started = timestamp_before(d, cb, *log).has_value();
    if (!d.serving && d.next.CmdBuildClusterAccelerationStructureIndirectNV)
        d.next.CmdBuildClusterAccelerationStructureIndirectNV(cb, p_command_infos);
    auto ended = timestamp_after(d, cb, *log, started);
    if (pause_after) {
        PausePoint after;
        after.pause_id = pause_id;
        after.phase = PausePhase::kAfterCommand;
        after.last_of_command = true;
        after.parameters = parameters;
        record_pause(d, cb, *log, after);
    }
    if (d.sink)
        log->recorded.commands.push_back(ClusterBuildCommand{*parameters, pause_id, d.serving});
    if (ended) log->recorded.commands.push_back(*ended);
}

VKAPI_ATTR void VKAPI_CALL GetClusterAccelerationStructureBuildSizesNV(
    VkDevice device, const VkClusterAccelerationStructureInputInfoNV* p_info,
    VkAccelerationStructureBuildSizesInfoKHR* p_size_info) {
    DeviceState& d = *find_device(dispatch_key(device));
    BuildSizesQuery query;
    if (d.serving || !d.next.GetClusterAccelerationStructureBuildSizesNV) {
        served_cluster_build_sizes(*p_info, *p_size_info);
        cover_traceable_blas(d, *p_info, *p_size_info);
        query.answered_by_layer = true;
    } else {
        d.next.GetClusterAccelerationStructureBuildSizesNV(device, p_info, p_size_info);
    }
    if (!d.sink) return;
    query.device = handle_id(device);
    query.input = copy_cluster_input(*p_info);
    query.answer = *p_size_info;
    query.answer.pNext = nullptr;
    d.sink->build_sizes_queried(query);
}

VKAPI_ATTR void VKAPI_CALL CmdBuildAccelerationStructureNV(
    VkCommandBuffer cb, const VkAccelerationStructureInfoNV* p_info, VkBuffer instance_data,
    VkDeviceSize instance_offset, VkBool32 update, VkAccelerationStructureNV dst,
    VkAccelerationStructureNV src, VkBuffer scratch, VkDeviceSize scratch_offset) {
    DeviceState& d = device_of(cb);
    auto c = std::make_shared<BuildAccelerationStructureNVCommand>();
    c->type = p_info->type;
    c->flags = p_info->flags;
    c->instance_count = p_info->instanceCount;
    for (uint32_t i = 0; i < p_info->geometryCount; ++i) {
        VkGeometryNV g = p_info->pGeometries[i];
        g.pNext = nullptr;
        g.geometry.triangles.pNext = nullptr;
        g.geometry.aabbs.pNext = nullptr;
        c->geometries.push_back(g);
    }
    c->instance_data = handle_id(instance_data);
    c->instance_offset = instance_offset;
    c->update = update;
    c->dst = handle_id(dst);
    c->src = handle_id(src);
    c->scratch = handle_id(scratch);
    c->scratch_offset = scratch_offset;
    auto log = log_of(d, cb);
    if (d.capturing_now()) {  // inputs only: the NV structure's own memory is opaque to the layer
        c->pause_id = ++d.pause_counter;
        PausePoint before;
        before.pause_id = c->pause_id;
        before.build_nv = c;
        record_pause(d, cb, *log, before);
    }
    const bool started = timestamp_before(d, cb, *log).has_value();
    d.next.CmdBuildAccelerationStructureNV(cb, p_info, instance_data, instance_offset, update, dst,
                                           src, scratch, scratch_offset);
    auto ended = timestamp_after(d, cb, *log, started);
    if (d.sink) log->recorded.commands.push_back(*c);
    if (ended) log->recorded.commands.push_back(*ended);
}

VKAPI_ATTR void VKAPI_CALL CmdCopyMemoryToAccelerationStructureKHR(
    VkCommandBuffer cb, const VkCopyMemoryToAccelerationStructureInfoKHR* p_info) {
    DeviceState& d = device_of(cb);
    auto c = std::make_shared<CopyMemoryToAccelerationStructureCommand>();
    c->src = p_info->src.deviceAddress;
    c->dst = handle_id(p_info->dst);
    c->mode = p_info->mode;
    auto log = log_of(d, cb);
    if (d.capturing_now()) {
        c->pause_id = ++d.pause_counter;
        PausePoint before;
        before.pause_id = c->pause_id;
        before.copy_to_acceleration_structure = c;
        record_pause(d, cb, *log, before);
    }
    const bool started = timestamp_before(d, cb, *log).has_value();
    d.next.CmdCopyMemoryToAccelerationStructureKHR(cb, p_info);
    auto ended = timestamp_after(d, cb, *log, started);
    if (d.sink) log->recorded.commands.push_back(*c);
    if (ended) log->recorded.commands.push_back(*ended);
}

}  // namespace

void record_pause_before_command(DeviceState& d, VkCommandBuffer cb, CommandBufferLog& log,
                                 PausePoint pause) {
    record_pause(d, cb, log, std::move(pause));
}

void clear_command_buffer_log(DeviceState& d, CommandBufferLog& log) {
    if (d.pauses) d.pauses->forget_events(log.events);
    // No execution is pending (the command buffer is re-begun, reset or freed): an abandoned
    // pause may have left an event set, so each starts over unsignalled.
    for (VkEvent event : log.events) {
        d.next.ResetEvent(d.device, event);
        log.spare_events.push_back(event);
    }
    log.events.clear();
    for (auto& staging : log.staging) destroy_staging(d, *staging);
    log.staging.clear();
    log.pauses.clear();
    if (log.timestamp_pool) {
        // Resetting, freeing or re-beginning is allowed only once no execution is pending: what was
        // not read yet is final now.
        const VkQueryPool pool = log.timestamp_pool;
        read_completed_timestamps(d, [pool](const DeviceState::PendingTimestampRead& r) {
            return r.pool == pool;
        });
        log.spare_timestamp_pool = pool;  // the next recording resets it before its first query
    }
    log.timestamp_pool = VK_NULL_HANDLE;
    log.timestamps_written = 0;
    log.timestamp_read_pause_id = 0;
    log.recorded.commands.clear();
    log.compute_pipeline = 0;
    log.graphics_pipeline = 0;
    log.ray_tracing_pipeline = 0;
    log.compute_sets.clear();
    log.graphics_sets.clear();
    log.ray_tracing_sets.clear();
    for (auto& pushed : log.pushed_acceleration_structures) pushed.clear();
    for (auto& pushed : log.pushed_buffers) pushed.clear();
    log.push_constants.clear();
    log.consumers.clear();
    log.descriptor_buffers.clear();
    for (auto& offsets : log.descriptor_buffer_offsets) offsets.clear();
}

void release_command_buffer_log(DeviceState& d, CommandBufferLog& log) {
    clear_command_buffer_log(d, log);
    for (VkEvent event : log.spare_events) d.next.DestroyEvent(d.device, event, nullptr);
    log.spare_events.clear();
    if (log.spare_timestamp_pool)
        d.next.DestroyQueryPool(d.device, log.spare_timestamp_pool, nullptr);
    log.spare_timestamp_pool = VK_NULL_HANDLE;
}

void record_command_with_pause(VkCommandBuffer cb, PausePoint* pause,
                               const std::function<void()>& forward, RecordedCommand command) {
    DeviceState& d = device_of(cb);
    auto log = log_of(d, cb);
    if (!pause) {
        forward();
        if (d.sink) log->recorded.commands.push_back(std::move(command));
        return;
    }
    if (pause->pause_id) record_pause(d, cb, *log, *pause);
    const bool started = timestamp_before(d, cb, *log).has_value();
    forward();
    auto ended = timestamp_after(d, cb, *log, started);
    if (d.sink) log->recorded.commands.push_back(std::move(command));
    if (ended) log->recorded.commands.push_back(*ended);
}

PFN_vkVoidFunction command_hook(const char* name) {
#define HOOK(fn) \
    { "vk" #fn, (PFN_vkVoidFunction)fn }
    static const std::map<std::string, PFN_vkVoidFunction, std::less<>> kHooks = {
        HOOK(BeginCommandBuffer),
        HOOK(EndCommandBuffer),
        HOOK(ResetCommandBuffer),
        HOOK(AllocateCommandBuffers),
        HOOK(FreeCommandBuffers),
        HOOK(ResetCommandPool),
        HOOK(DestroyCommandPool),
        HOOK(CmdPipelineBarrier),
        HOOK(CmdPipelineBarrier2),
        HOOK(CmdPipelineBarrier2KHR),
        HOOK(CmdSetEvent),
        HOOK(CmdSetEvent2),
        HOOK(CmdSetEvent2KHR),
        HOOK(CmdResetEvent),
        HOOK(CmdResetEvent2),
        HOOK(CmdResetEvent2KHR),
        HOOK(CmdWaitEvents),
        HOOK(CmdWaitEvents2),
        HOOK(CmdWaitEvents2KHR),
        HOOK(CmdCopyBuffer),
        HOOK(CmdCopyBuffer2),
        HOOK(CmdCopyBuffer2KHR),
        HOOK(CmdFillBuffer),
        HOOK(CmdUpdateBuffer),
        HOOK(CmdDispatch),
        HOOK(CmdDispatchIndirect),
        HOOK(CmdBindPipeline),
        HOOK(CmdBindDescriptorSets),
        HOOK(UpdateDescriptorSets),
        HOOK(CmdExecuteCommands),
        HOOK(CmdBuildAccelerationStructureNV),
        HOOK(CmdCopyMemoryToAccelerationStructureKHR),
    };
    auto it = kHooks.find(name);
    return it == kHooks.end() ? nullptr : it->second;
}

PFN_vkVoidFunction cluster_hook(const char* name) {
    if (std::strcmp(name, "vkCmdBuildClusterAccelerationStructureIndirectNV") == 0)
        return (PFN_vkVoidFunction)CmdBuildClusterAccelerationStructureIndirectNV;
    if (std::strcmp(name, "vkGetClusterAccelerationStructureBuildSizesNV") == 0)
        return (PFN_vkVoidFunction)GetClusterAccelerationStructureBuildSizesNV;
    return nullptr;
}

}  // namespace clastrace::capture
