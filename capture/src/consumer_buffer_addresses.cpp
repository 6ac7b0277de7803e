// SPDX-License-Identifier: Apache-2.0
// Acceleration-structure addresses stored in the buffers a consumer binds (source 4 of a
// consumer's structures). A shader that turns a 64-bit value from memory into a structure
// (OpConvertUToAccelerationStructureKHR; spirv_scan.h) can reach any structure whose address
// those buffers hold. For such a consumer the layer reads, at recording and again at submission,
// the storage and uniform buffers of its bound and pushed descriptor sets through its own
// mapping, and counts every 8-byte value equal to the address of a live structure of the device:
// a value that merely equals an address counts too ("possible" reach), as for push constants.
#include "command_buffer_log.h"
#include "layer_state.h"

#include <algorithm>
#include <atomic>
#include <cstring>

namespace clastrace::capture {
namespace {

using Source = ReachableAccelerationStructure::Source;

void say_not_host_visible(const std::string& why) {
    static std::atomic<bool> said{false};
    if (!said.exchange(true))
        log_message(LogLevel::kInfo,
                    "a buffer bound to a consumer that converts addresses from memory into "
                    "acceleration structures is not searched for their addresses: %s",
                    why.c_str());
}

// The bytes of `b` as the host sees them now through the layer's mapping; null (and a note,
// once) where the memory is not host visible or the range is not inside the buffer.
const uint8_t* host_bytes_of(DeviceState& d, const BoundStorageBuffer& b, VkDeviceSize* size) {
    std::string why;
    auto buffer = d.memory_map.buffer(b.buffer);
    if (!buffer || b.offset >= buffer->size) {
        say_not_host_visible("buffer " + std::to_string(b.buffer) + " is not a live buffer there");
        return nullptr;
    }
    *size = b.range == VK_WHOLE_SIZE ? buffer->size - b.offset
                                     : std::min(b.range, buffer->size - b.offset);
    auto resolved = d.memory_map.resolve_buffer(b.buffer, b.offset, *size, why);
    if (!resolved || !resolved->host) {
        say_not_host_visible(resolved ? "its memory is not host visible" : why);
        return nullptr;
    }
    return resolved->host;
}

// Every 8-byte value of `b` equal to a known structure address, at each 4-byte offset (scalar
// block layout lets a uint64_t sit there). The record has no field for where the value was
// found beyond set and binding: array_element holds its byte offset from the descriptor's
// offset, so the descriptor's own array element is not kept.
void add_addresses_in(DeviceState& d, const BoundStorageBuffer& b,
                      std::vector<ReachableAccelerationStructure>& out) {
    VkDeviceSize size = 0;
    const uint8_t* bytes = host_bytes_of(d, b, &size);
    if (!bytes || size < sizeof(uint64_t)) return;
    std::lock_guard lock(d.acceleration_structure_addresses_mutex);
    const auto& known = d.acceleration_structures_by_address;
    if (known.empty()) return;
    VkDeviceAddress lowest = ~0ull, highest = 0;  // a cheap test before each lookup
    for (const auto& [address, handle] : known) {
        lowest = std::min(lowest, address);
        highest = std::max(highest, address);
    }
    for (VkDeviceSize offset = 0; offset + sizeof(uint64_t) <= size; offset += 4) {
        uint64_t value = 0;
        std::memcpy(&value, bytes + offset, sizeof value);
        if (value < lowest || value > highest) continue;
        auto it = known.find(value);
        if (it == known.end()) continue;
        ReachableAccelerationStructure r;
        r.set = b.set;
        r.binding = b.binding;
        r.array_element = uint32_t(std::min<VkDeviceSize>(offset, UINT32_MAX));
        r.source = Source::kMemory;
        r.acceleration_structure = it->second;
        r.address = value;
        out.push_back(r);
    }
}

}  // namespace

void add_buffer_structure_addresses(DeviceState& d, const ConsumerBindings& bindings,
                                    std::vector<ReachableAccelerationStructure>& out) {
    if (!bindings.search_bound_buffers) return;
    for (const BoundStorageBuffer& b : bound_address_buffers(d, bindings.sets))
        add_addresses_in(d, b, out);
    for (const auto& [key, b] : bindings.pushed_buffers) add_addresses_in(d, b, out);
}

}  // namespace clastrace::capture
