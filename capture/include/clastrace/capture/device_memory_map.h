// SPDX-License-Identifier: Apache-2.0
// The buffers and memory allocations of one VkDevice, and the lookup from a device address to
// the bytes behind it: the layer follows the pointers a cluster build reads with it.
#pragma once

#include <vulkan/vulkan_core.h>

#include <cstdint>
#include <atomic>
#include <map>
#include <mutex>
#include <optional>
#include <string>
#include <unordered_map>
#include <vector>

namespace clastrace::capture {

struct TrackedMemory {
    uint64_t handle = 0;
    VkDeviceSize size = 0;
    uint32_t type_index = 0;
    VkMemoryPropertyFlags property_flags = 0;
    uint8_t* host_base =
        nullptr;  // the layer's persistent mapping of the whole allocation, if host visible
};

struct TrackedBuffer {
    uint64_t handle = 0;
    VkDeviceSize size = 0;
    VkBufferUsageFlags usage = 0;
    VkBufferCreateFlags flags = 0;
    uint64_t memory = 0;  // 0 until bound
    VkDeviceSize memory_offset = 0;
    VkDeviceAddress address = 0;  // 0 until the application asked for it
};

// Whether `b` is a plain (not sparse) buffer whose addresses hold [address, address + size): its
// memory then holds the range at the same offset, wherever in the buffer it lies.
inline bool plainly_holds(const TrackedBuffer& b, VkDeviceAddress address, VkDeviceSize size) {
    if (b.flags & VK_BUFFER_CREATE_SPARSE_BINDING_BIT) return false;
    if (address < b.address) return false;
    const VkDeviceSize offset = address - b.address;
    return offset < b.size && size <= b.size - offset;
}

// Where a device address range lives; `host` is null when the memory is not mapped by the layer.
struct ResolvedRange {
    TrackedBuffer buffer;
    VkDeviceSize offset_in_buffer = 0;
    TrackedMemory memory;
    uint8_t* host = nullptr;

    // The same buffer's range at `address` (which it must hold): the offset and host pointer
    // follow, as resolve() would give them.
    void aim_at(VkDeviceAddress address) {
        offset_in_buffer = address - buffer.address;
        host =
            memory.host_base ? memory.host_base + buffer.memory_offset + offset_in_buffer : nullptr;
    }
};

class DeviceMemoryMap {
public:
    void add_memory(const TrackedMemory& memory);
    void remove_memory(uint64_t handle);
    std::optional<TrackedMemory> memory(uint64_t handle) const;

    void add_buffer(const TrackedBuffer& buffer);
    void bind_buffer(uint64_t buffer, uint64_t memory, VkDeviceSize offset);
    void set_buffer_address(uint64_t buffer, VkDeviceAddress address);
    // One VkSparseMemoryBind of a sparse buffer (vkQueueBindSparse): [resource_offset, + size)
    // of the buffer is now `memory` at `memory_offset` (0: unbound), replacing what was there.
    // resolve() then maps the buffer's addresses piece by piece to the memory bound under them.
    void bind_sparse(uint64_t buffer, VkDeviceSize resource_offset, VkDeviceSize size,
                     uint64_t memory, VkDeviceSize memory_offset);
    void remove_buffer(uint64_t handle);
    std::optional<TrackedBuffer> buffer(uint64_t handle) const;

    // The buffer (with a bound, live allocation) that holds all of [address, address + size).
    // Aliasing buffers may share addresses; any one that holds the whole range is as good.
    // On failure `why` names the rule broken, for the capture's issue list.
    std::optional<ResolvedRange> resolve(VkDeviceAddress address, VkDeviceSize size,
                                         std::string& why) const;

    // Copies [address, address + size) from the layer's mapping. False with `why` when the range
    // is not inside one bound buffer or its memory is not host visible.
    bool read(VkDeviceAddress address, VkDeviceSize size, std::vector<uint8_t>& out,
              std::string& why) const;

    // The same for a range named by buffer handle and offset (commands that take VkBuffers).
    std::optional<ResolvedRange> resolve_buffer(uint64_t buffer, VkDeviceSize offset,
                                                VkDeviceSize size, std::string& why) const;

    // Every buffer with a queried address and live host-mapped memory bound, from its first byte
    // (offsetInBuffer 0): what a served build may touch. A sparse buffer gives one entry per run
    // of its bound pages that lie one after another in one allocation, each as if it were a
    // buffer of its own at the run's addresses (buffer.address, size and memory_offset are the
    // run's), so a served build reads and writes the memory bound there; unbound pages none.
    std::vector<ResolvedRange> host_addressed_buffers() const;

    // Every buffer with a queried address and live memory bound that the layer has not mapped
    // (memory the host cannot map), whose usage has a bit of `usageMask`: what a pause must copy
    // into host-visible staging to read it.
    std::vector<TrackedBuffer> unmapped_addressed_buffers(VkBufferUsageFlags usage_mask) const;

    // The device-address ranges [begin, end) of the addressed buffers bound to `memory` (a
    // sparse buffer: its pages bound there): what goes when the memory is freed.
    std::vector<std::pair<VkDeviceAddress, VkDeviceAddress>> address_ranges_in(
        uint64_t memory) const;

    // Counts the changes that can move what resolve() answers (memory, buffers, binds,
    // addresses): equal counts, equal answers. The host-write watch reuses resolved walks by it.
    uint64_t changes() const { return changes_.load(std::memory_order_acquire); }

private:
    // [offset, offset + size) of `b` in its memory (mutex_ held): a plain buffer's bound
    // memory, or for a sparse buffer the one memory its binds put the whole range in,
    // contiguously (a range over unbound pages or over several allocations is refused).
    std::optional<ResolvedRange> resolve_in(const TrackedBuffer& b, VkDeviceSize offset,
                                            VkDeviceSize size, std::string& why) const;
    // host_addressed_buffers' entries for the sparse buffer `b` (mutex_ held).
    void append_host_mapped_sparse_runs(const TrackedBuffer& b,
                                        std::vector<ResolvedRange>& out) const;
    struct SparsePage {  // a bound part of a sparse buffer
        VkDeviceSize end = 0;
        uint64_t memory = 0;
        VkDeviceSize memory_offset = 0;
    };
    // Sparse buffer -> its bound parts, keyed by the offset in the buffer where each begins.
    std::unordered_map<uint64_t, std::map<VkDeviceSize, SparsePage>> sparse_pages_;
    mutable std::mutex mutex_;
    std::atomic<uint64_t> changes_{0};
    void changed() { changes_.fetch_add(1, std::memory_order_acq_rel); }
    std::unordered_map<uint64_t, TrackedMemory> memories_;
    std::unordered_map<uint64_t, TrackedBuffer> buffers_;
    std::multimap<VkDeviceAddress, uint64_t> buffers_by_address_;
    VkDeviceSize largest_addressed_buffer_ = 0;
    // The entry of the buffer the last resolve() landed in (end() when none): a walk resolves
    // runs of addresses inside one buffer, and while no entry lies between it and the next
    // address it is the one resolve() would try first. Erasing entries forgets it.
    mutable std::multimap<VkDeviceAddress, uint64_t>::const_iterator last_resolved_ =
        buffers_by_address_.cend();
    void forget_last_resolved() { last_resolved_ = buffers_by_address_.cend(); }
    std::optional<ResolvedRange> resolve_in_last(VkDeviceAddress address, VkDeviceSize size) const;
};

}  // namespace clastrace::capture
