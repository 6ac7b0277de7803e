// SPDX-License-Identifier: Apache-2.0
// What the layer keeps per application command buffer between vkBeginCommandBuffer and its
// reset: the recorded commands, and the pause points (with the layer's events) to expect when
// it is submitted.
#pragma once

#include "pause_worker.h"

#include <functional>
#include <map>
#include <vector>

namespace clastrace::capture {

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
    std::map<uint32_t, std::pair<VkDescriptorSet, std::vector<uint32_t>>>
        compute_sets;  // set -> (set, dynamic offsets)
};

// Forwards a command (`forward`) and logs `command` (khr_commands.cpp). With `pause`: a captured
// command, between the layer's timestamps, after `pause` (recorded when its pause_id is not 0,
// i.e. when capturing now). Without: logged only.
void record_command_with_pause(VkCommandBuffer cb, PausePoint* pause,
                               const std::function<void()>& forward, RecordedCommand command);

// Clears `log` for a new recording; its events and query pool become spares.
void clear_command_buffer_log(DeviceState& device, CommandBufferLog& log);
// Clears `log` and destroys the layer's objects: the command buffer is freed (or the device).
void release_command_buffer_log(DeviceState& device, CommandBufferLog& log);

}  // namespace clastrace::capture
