// SPDX-License-Identifier: Apache-2.0
// What the layer keeps per application command buffer between vkBeginCommandBuffer and its
// reset: the recorded commands, and the pause points (with the layer's events) to expect when
// it is submitted.
#pragma once

#include "pause_worker.h"

#include <functional>
#include <map>
#include <tuple>
#include <vector>

namespace clastrace::capture {

using BoundDescriptorSets =
    std::map<uint32_t, std::pair<VkDescriptorSet, std::vector<uint32_t>>>;  // set -> (set, offsets)
using PushedAccelerationStructures =  // (set, binding, element) -> structure
    std::map<std::tuple<uint32_t, uint32_t, uint32_t>, ReachableAccelerationStructure>;
using PushedBuffers =  // (set, binding, element) -> storage buffer
    std::map<std::tuple<uint32_t, uint32_t, uint32_t>, BoundStorageBuffer>;

// A set taken from a descriptor buffer (vkCmdSetDescriptorBufferOffsetsEXT): its layout and the
// address its descriptors start at (the bound buffer's address plus the offset).
struct DescriptorBufferSet {
    uint64_t set_layout = 0;
    VkDeviceAddress address = 0;
};
using DescriptorBufferSets = std::map<uint32_t, DescriptorBufferSet>;  // set -> where

// What one consumer (rays, a ray-query dispatch or draw) was recorded with, kept so that the
// structures it reaches are read again at each submission (refresh_consumer_structures): a set
// updated after binding (UPDATE_AFTER_BIND) holds, when the command runs, what was written last.
struct ConsumerBindings {
    int bind_point = 0;  // bind_point_index
    BoundDescriptorSets sets;
    PushedAccelerationStructures pushed;
    std::vector<uint8_t> push_constants;
    DescriptorBufferSets buffer_sets;
    // The pipeline converts values from memory into structures: its bound storage buffers (the
    // sets' and the pushed ones) are searched for structure addresses.
    bool search_bound_buffers = false;
    PushedBuffers pushed_buffers;
};

struct CommandBufferLog {
    RecordedCommandBuffer recorded;
    std::vector<PausePoint> pauses;                    // in execution order, secondaries' included
    std::vector<VkEvent> events;                       // created by the layer for this recording
    std::vector<std::shared_ptr<StagingSet>> staging;  // the pauses' staging buffers, likewise
    // GPU timestamps around the captured commands (primary command buffers only): the layer's
    // query pool for this recording, queries used, and the id its readback is known by.
    VkQueryPool timestamp_pool = VK_NULL_HANDLE;
    uint32_t timestamps_written = 0;
    uint64_t timestamp_read_pause_id = 0;
    // The layer's objects of earlier recordings, reused by the next: creating and destroying
    // events and query pools every frame costs driver work (on NVIDIA's driver, page-attribute
    // changes whose TLB flushes interrupt every core).
    std::vector<VkEvent> spare_events;
    VkQueryPool spare_timestamp_pool = VK_NULL_HANDLE;
    // Compute binding state, for the storage buffers each dispatch sees.
    uint64_t compute_pipeline = 0;
    uint64_t graphics_pipeline = 0;  // for draws that may write through device addresses
    uint64_t ray_tracing_pipeline = 0;
    using BoundSets = BoundDescriptorSets;
    BoundSets compute_sets;  // set -> (set, dynamic offsets)
    BoundSets graphics_sets, ray_tracing_sets;
    // Acceleration structures pushed with vkCmdPushDescriptorSet*KHR, per bind point (compute,
    // graphics, ray tracing), keyed by (set, binding, element).
    PushedAccelerationStructures pushed_acceleration_structures[3];
    PushedBuffers pushed_buffers[3];      // storage buffers pushed likewise
    std::vector<uint8_t> push_constants;  // the bytes vkCmdPushConstants set so far
    // VK_EXT_descriptor_buffer: the bound descriptor buffers' addresses (by binding index), and
    // per bind point the sets taken from them: set -> (set layout, buffer index, offset).
    std::vector<VkDeviceAddress> descriptor_buffers;
    struct BufferSetOffset {
        uint64_t set_layout = 0;
        uint32_t buffer_index = 0;
        VkDeviceSize offset = 0;
    };
    std::map<uint32_t, BufferSetOffset> descriptor_buffer_offsets[3];
    // One entry per consumer recorded, in recording order (reachable_acceleration_structures,
    // which reads a const log, appends them).
    mutable std::vector<ConsumerBindings> consumers;

    // vkCmdBindDescriptorSets (or vkCmdSetDescriptorBufferOffsetsEXT) bound sets [first, first +
    // count) at `bind_point`: what was pushed or taken from a descriptor buffer there before is
    // no longer bound.
    void forget_pushed_sets(int index, uint32_t first, uint32_t count) {
        if (index < 0) return;
        auto& pushed = pushed_acceleration_structures[index];
        for (auto it = pushed.begin(); it != pushed.end();) {
            const uint32_t set = std::get<0>(it->first);
            it = set >= first && set - first < count ? pushed.erase(it) : std::next(it);
        }
        auto& buffers = pushed_buffers[index];
        for (auto it = buffers.begin(); it != buffers.end();) {
            const uint32_t set = std::get<0>(it->first);
            it = set >= first && set - first < count ? buffers.erase(it) : std::next(it);
        }
        auto& from_buffers = descriptor_buffer_offsets[index];
        for (auto it = from_buffers.begin(); it != from_buffers.end();)
            it = it->first >= first && it->first - first < count ? from_buffers.erase(it)
                                                                 : std::next(it);
    }
    // The sets bound at `bind_point` (null for bind points the layer does not follow).
    BoundSets* sets_at(VkPipelineBindPoint bind_point) {
        switch (bind_point) {
        case VK_PIPELINE_BIND_POINT_COMPUTE: return &compute_sets;
        case VK_PIPELINE_BIND_POINT_GRAPHICS: return &graphics_sets;
        case VK_PIPELINE_BIND_POINT_RAY_TRACING_KHR: return &ray_tracing_sets;
        default: return nullptr;
        }
    }
};

// Forwards a command (`forward`) and logs `command` (khr_commands.cpp). With `pause`: a captured
// command, between the layer's timestamps, after `pause` (recorded when its pause_id is not 0,
// i.e. when capturing now). Without: logged only.
void record_command_with_pause(VkCommandBuffer cb, PausePoint* pause,
                               const std::function<void()>& forward, RecordedCommand command);
// Index of a followed bind point in per-bind-point arrays (0 compute, 1 graphics, 2 ray
// tracing; -1 for others).
inline int bind_point_index(VkPipelineBindPoint bind_point) {
    switch (bind_point) {
    case VK_PIPELINE_BIND_POINT_COMPUTE: return 0;
    case VK_PIPELINE_BIND_POINT_GRAPHICS: return 1;
    case VK_PIPELINE_BIND_POINT_RAY_TRACING_KHR: return 2;
    default: return -1;
    }
}

// The log of `cb`, created on first use (layer_commands.cpp).
std::shared_ptr<CommandBufferLog> command_buffer_log_of(DeviceState& d, VkCommandBuffer cb);

// Records a pause (pause_worker.h) into `cb` here: the queue stops before the next command
// (layer_commands.cpp).
void record_pause_before_command(DeviceState& d, VkCommandBuffer cb, CommandBufferLog& log,
                                 PausePoint pause);

// The storage-buffer descriptors of the bound `sets` (dynamic offsets applied;
// layer_commands.cpp).
std::vector<BoundStorageBuffer> bound_storage_buffers(DeviceState& d,
                                                      const CommandBufferLog::BoundSets& sets);
// The storage- and uniform-buffer descriptors of the bound `sets` (dynamic offsets applied):
// where a consumer's shader may load a structure address from (consumer_buffer_addresses.cpp).
std::vector<BoundStorageBuffer> bound_address_buffers(DeviceState& d,
                                                      const CommandBufferLog::BoundSets& sets);

// What a consumer at `bind_point` can reach: the acceleration-structure descriptors of the
// bound sets, the pushed ones, and push-constant values equal to a known address
// (consumer_commands.cpp).
std::vector<ReachableAccelerationStructure> reachable_acceleration_structures(
    DeviceState& d, const CommandBufferLog& log, VkPipelineBindPoint bind_point);

// The sets taken from descriptor buffers at bind point `index`, with the addresses their
// descriptors start at now (consumer_descriptor_buffers.cpp).
DescriptorBufferSets descriptor_buffer_sets_at(const CommandBufferLog& log, int index);
// The acceleration structures whose descriptors (vkGetDescriptorEXT answers) `sets` hold now, read
// from host-visible memory; source kDescriptorBuffer (consumer_descriptor_buffers.cpp).
void add_descriptor_buffer_structures(DeviceState& d, const DescriptorBufferSets& sets,
                                      std::vector<ReachableAccelerationStructure>& out);

// The acceleration structures whose addresses the storage buffers of `bindings` hold now, when
// its pipeline converts values from memory into structures; source kMemory
// (consumer_buffer_addresses.cpp).
void add_buffer_structure_addresses(DeviceState& d, const ConsumerBindings& bindings,
                                    std::vector<ReachableAccelerationStructure>& out);

// Clears `log` for a new recording; its events and query pool become spares.
void clear_command_buffer_log(DeviceState& device, CommandBufferLog& log);
// Clears `log` and destroys the layer's objects: the command buffer is freed (or the device).
void release_command_buffer_log(DeviceState& device, CommandBufferLog& log);

}  // namespace clastrace::capture
