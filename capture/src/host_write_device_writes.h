// SPDX-License-Identifier: Apache-2.0
// What the device itself may write while a watched submission is pending (host_write_watch.h):
// a mapped range whose bytes changed between vkQueueSubmit and the wait is a host write only
// if no command in flight could have written it. The layer knows those commands' destinations
// from what it recorded: copies, fills and updates, the storage buffers bound to dispatches,
// and the destinations, arrays and scratch of builds.
#pragma once

#include <vulkan/vulkan_core.h>

#include <cstdint>
#include <vector>

namespace clastrace::capture {

struct DeviceState;

// Bytes [begin, end) of one device memory allocation.
struct MemorySpan {
    // A shader that writes through buffer device addresses may write any memory.
    static constexpr uint64_t kAnyMemory = ~0ull;
    uint64_t memory = 0;
    VkDeviceSize begin = 0, end = 0;
    bool overlaps(const MemorySpan& o) const {
        if (memory == kAnyMemory || o.memory == kAnyMemory) return true;
        return memory == o.memory && begin < o.end && o.begin < end;
    }
};

// Every span the commands recorded into `command_buffers` (and the secondaries they execute)
// may write. Address-based destinations whose extent the command does not state (implicit
// data, scratch, the dst arrays) run to the end of the buffer holding their address.
std::vector<MemorySpan> device_writes_of(DeviceState& d,
                                         const std::vector<uint64_t>& command_buffers);

bool overlaps_any(const std::vector<MemorySpan>& spans, const MemorySpan& span);

}  // namespace clastrace::capture
