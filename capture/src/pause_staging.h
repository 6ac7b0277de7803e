// SPDX-License-Identifier: Apache-2.0
// Memory the host cannot map (device-local without HOST_VISIBLE, or every allocation under
// CLASTRACE_FORCE_STAGING=1) reaches the pause worker through staging: right before the pause
// the queue copies each such buffer a cluster build may touch into one host-visible buffer of
// the layer's; the worker reads (and, serving, writes) that copy; right after the pause the
// queue copies it back, so what the engine wrote lands in the application's buffers exactly.
//
// Which addresses a build reaches is known only when it executes, so the copy holds every
// unmapped buffer with an acceleration-structure usage (build input or storage), whole: exact,
// at the price of one copy of those buffers per pause. Buffers without either usage are not
// staged; the capture names them as unreadable (the extension requires the usages anyway).
#pragma once

#include "clastrace/capture/device_memory_map.h"

#include <memory>
#include <vector>
#include <vulkan/vulkan_core.h>

namespace clastrace::capture {

struct DeviceState;

struct StagedBuffer {
    TrackedBuffer buffer;
    VkDeviceSize offset = 0;  // where its copy starts in the staging buffer
};

struct StagingSet {
    VkBuffer buffer = VK_NULL_HANDLE;
    VkDeviceMemory memory = VK_NULL_HANDLE;
    uint8_t* host = nullptr;
    bool coherent = true;
    bool cached = true;  // HOST_CACHED: plain loads; otherwise the worker uses streaming loads
    std::vector<StagedBuffer> buffers;

    const StagedBuffer* find(uint64_t buffer) const;
};

constexpr VkBufferUsageFlags kStagedUsage =
    VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR |
    VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR;

// A staging buffer for the device's unmapped buffers of kStagedUsage; null when there are
// none, or when it cannot be created (said once on stderr: those builds are then captured
// without the unmapped ranges, which the capture lists as issues).
std::shared_ptr<StagingSet> create_staging(DeviceState& device);
void destroy_staging(DeviceState& device, StagingSet& staging);

// Recorded before the pause's own barrier (which makes the copies visible to the host).
void record_copies_to_staging(DeviceState& device, VkCommandBuffer cb, const StagingSet& staging);
// Recorded after the pause's wait: the staged bytes (as the worker left them) go back.
void record_copies_from_staging(DeviceState& device, VkCommandBuffer cb, const StagingSet& staging);

}  // namespace clastrace::capture
