// SPDX-License-Identifier: Apache-2.0
#include "clastrace/capture/device_memory_map.h"
#include "clastrace/common/hex.h"

#include <cstdio>
#include <cstring>

namespace clastrace::capture {
namespace {

using common::hex;

void erase_address(std::multimap<VkDeviceAddress, uint64_t>& by_address, VkDeviceAddress address,
                   uint64_t buffer) {
    auto [first, last] = by_address.equal_range(address);
    for (auto it = first; it != last; ++it) {
        if (it->second == buffer) {
            by_address.erase(it);
            return;
        }
    }
}

}  // namespace

void DeviceMemoryMap::add_memory(const TrackedMemory& memory) {
    std::lock_guard lock(mutex_);
    changed();
    memories_[memory.handle] = memory;
}

void DeviceMemoryMap::remove_memory(uint64_t handle) {
    std::lock_guard lock(mutex_);
    changed();
    memories_.erase(handle);
}

std::optional<TrackedMemory> DeviceMemoryMap::memory(uint64_t handle) const {
    std::lock_guard lock(mutex_);
    auto it = memories_.find(handle);
    if (it == memories_.end()) return std::nullopt;
    return it->second;
}

void DeviceMemoryMap::add_buffer(const TrackedBuffer& buffer) {
    std::lock_guard lock(mutex_);
    changed();
    forget_last_resolved();  // a handle added again may have another address
    buffers_[buffer.handle] = buffer;
}

void DeviceMemoryMap::bind_buffer(uint64_t buffer, uint64_t memory, VkDeviceSize offset) {
    std::lock_guard lock(mutex_);
    changed();
    auto it = buffers_.find(buffer);
    if (it == buffers_.end()) return;
    it->second.memory = memory;
    it->second.memory_offset = offset;
}

void DeviceMemoryMap::set_buffer_address(uint64_t buffer, VkDeviceAddress address) {
    std::lock_guard lock(mutex_);
    auto it = buffers_.find(buffer);
    if (it == buffers_.end() || address == 0) return;
    if (it->second.address == address) return;
    changed();
    if (it->second.address != 0) erase_address(buffers_by_address_, it->second.address, buffer);
    forget_last_resolved();
    it->second.address = address;
    buffers_by_address_.emplace(address, buffer);
    if (it->second.size > largest_addressed_buffer_) largest_addressed_buffer_ = it->second.size;
}

void DeviceMemoryMap::remove_buffer(uint64_t handle) {
    std::lock_guard lock(mutex_);
    changed();
    auto it = buffers_.find(handle);
    if (it == buffers_.end()) return;
    if (it->second.address != 0) erase_address(buffers_by_address_, it->second.address, handle);
    forget_last_resolved();
    buffers_.erase(it);
    sparse_pages_.erase(handle);
}

std::optional<TrackedBuffer> DeviceMemoryMap::buffer(uint64_t handle) const {
    std::lock_guard lock(mutex_);
    auto it = buffers_.find(handle);
    if (it == buffers_.end()) return std::nullopt;
    return it->second;
}

std::optional<ResolvedRange> DeviceMemoryMap::resolve(VkDeviceAddress address, VkDeviceSize size,
                                                      std::string& why) const {
    std::lock_guard lock(mutex_);
    if (size > 0 && address + size < address) {
        why = "address range " + hex(address) + "+" + hex(size) + " wraps around the address space";
        return std::nullopt;
    }
    if (auto r = resolve_in_last(address, size)) return r;
    // Candidates start at or below `address`; none that starts more than the largest buffer's size
    // below it can reach it, which bounds the walk.
    auto it = buffers_by_address_.upper_bound(address);
    bool saw_containing_start = false;
    while (it != buffers_by_address_.begin()) {
        --it;
        if (address - it->first > largest_addressed_buffer_) break;
        const TrackedBuffer& b = buffers_.at(it->second);
        const VkDeviceSize offset = address - b.address;
        if (offset >= b.size && !(offset == b.size && size == 0)) continue;
        saw_containing_start = true;
        if (size > b.size - offset) continue;
        std::string sparse_why;
        if (auto r = resolve_in(b, offset, size, sparse_why)) {
            last_resolved_ = it;
            return r;
        }
        if (b.flags & VK_BUFFER_CREATE_SPARSE_BINDING_BIT) why = sparse_why;
    }
    if (!why.empty()) return std::nullopt;  // the sparse buffer holding it said why
    why = saw_containing_start
              ? "address range " + hex(address) + "+" + hex(size) +
                    " runs past the end of its buffer or the buffer has no live memory bound"
              : "device address " + hex(address) +
                    " is not inside any buffer whose address the application queried";
    return std::nullopt;
}

// The answer of resolve()'s walk when its first candidate is the last buffer resolved into (no
// entry starts after it at or below `address`) and that plain buffer holds the range: the walk
// would try it first and take it. Anything else goes the walk's way.
std::optional<ResolvedRange> DeviceMemoryMap::resolve_in_last(VkDeviceAddress address,
                                                              VkDeviceSize size) const {
    const auto last = last_resolved_;
    if (last == buffers_by_address_.cend() || last->first > address) return std::nullopt;
    const auto next = std::next(last);
    if (next != buffers_by_address_.cend() && next->first <= address) return std::nullopt;
    const auto b = buffers_.find(last->second);
    if (b == buffers_.end() || b->second.address != last->first ||
        !plainly_holds(b->second, address, size))
        return std::nullopt;
    std::string unused;
    return resolve_in(b->second, address - last->first, size, unused);
}

std::optional<ResolvedRange> DeviceMemoryMap::resolve_buffer(uint64_t buffer, VkDeviceSize offset,
                                                             VkDeviceSize size,
                                                             std::string& why) const {
    std::lock_guard lock(mutex_);
    auto it = buffers_.find(buffer);
    if (it == buffers_.end()) {
        why = "buffer " + hex(buffer) + " is not a live buffer";
        return std::nullopt;
    }
    const TrackedBuffer& b = it->second;
    if (offset > b.size || size > b.size - offset) {
        why = "range " + hex(offset) + "+" + hex(size) + " runs past the end of buffer " +
              hex(buffer) + " (size " + hex(b.size) + ")";
        return std::nullopt;
    }
    return resolve_in(b, offset, size, why);
}

std::optional<ResolvedRange> DeviceMemoryMap::resolve_in(const TrackedBuffer& b,
                                                         VkDeviceSize offset, VkDeviceSize size,
                                                         std::string& why) const {
    uint64_t memory = b.memory;
    VkDeviceSize memory_offset = b.memory_offset + offset;
    if (b.flags & VK_BUFFER_CREATE_SPARSE_BINDING_BIT) {
        // The pages over the range must follow each other in one allocation: the capture
        // reads them with one copy from the layer's mapping.
        auto pages = sparse_pages_.find(b.handle);
        memory = 0;
        if (pages != sparse_pages_.end()) {
            auto page = pages->second.upper_bound(offset);
            if (page != pages->second.begin()) --page;
            VkDeviceSize at = offset;
            while (page != pages->second.end() && page->first <= at && page->second.end > at) {
                const VkDeviceSize page_memory_offset =
                    page->second.memory_offset + (at - page->first);
                if (at == offset) {
                    memory = page->second.memory;
                    memory_offset = page_memory_offset;
                } else if (page->second.memory != memory ||
                           page_memory_offset != memory_offset + (at - offset)) {
                    break;
                }
                at = page->second.end;
                if (at >= offset + size) break;
                ++page;
            }
            if (at < offset + size || (size == 0 && at == offset)) memory = 0;
        }
        if (memory == 0) {
            why = "range " + hex(offset) + "+" + hex(size) + " of sparse buffer " + hex(b.handle) +
                  " is not bound contiguously to one memory object (unbound pages, or several "
                  "allocations)";
            return std::nullopt;
        }
    }
    auto mem = memories_.find(memory);
    if (memory == 0 || mem == memories_.end()) {
        why = "buffer " + hex(b.handle) + " has no live memory bound";
        return std::nullopt;
    }
    ResolvedRange r;
    r.buffer = b;
    // The memory the range is in, as if the whole buffer were bound there (so readers that add
    // offset_in_buffer to memory_offset land on the range's memory).
    r.buffer.memory = memory;
    r.buffer.memory_offset = memory_offset - offset;
    r.offset_in_buffer = offset;
    r.memory = mem->second;
    if (mem->second.host_base) r.host = mem->second.host_base + memory_offset;
    return r;
}

void DeviceMemoryMap::bind_sparse(uint64_t buffer, VkDeviceSize resource_offset, VkDeviceSize size,
                                  uint64_t memory, VkDeviceSize memory_offset) {
    std::lock_guard lock(mutex_);
    changed();
    if (size == 0 || resource_offset + size < resource_offset) return;
    std::map<VkDeviceSize, SparsePage>& pages = sparse_pages_[buffer];
    const VkDeviceSize end = resource_offset + size;
    // A rebind replaces what was bound over its range: cut those parts back to the rest.
    auto it = pages.upper_bound(resource_offset);
    if (it != pages.begin() && std::prev(it)->second.end > resource_offset) --it;
    while (it != pages.end() && it->first < end) {
        const VkDeviceSize begin = it->first;
        const SparsePage page = it->second;
        it = pages.erase(it);
        if (begin < resource_offset)
            pages.emplace(begin, SparsePage{resource_offset, page.memory, page.memory_offset});
        if (page.end > end)
            it = pages
                     .emplace(end,
                              SparsePage{page.end, page.memory, page.memory_offset + (end - begin)})
                     .first;
    }
    if (memory != 0) pages.emplace(resource_offset, SparsePage{end, memory, memory_offset});
}

bool DeviceMemoryMap::read(VkDeviceAddress address, VkDeviceSize size, std::vector<uint8_t>& out,
                           std::string& why) const {
    auto range = resolve(address, size, why);
    if (!range) return false;
    if (!range->host) {
        why = "memory behind " + hex(address) +
              " is not host visible (staging copies are not implemented yet)";
        return false;
    }
    out.resize(size);
    if (size) std::memcpy(out.data(), range->host, size);
    return true;
}

std::vector<ResolvedRange> DeviceMemoryMap::host_addressed_buffers() const {
    std::lock_guard lock(mutex_);
    std::vector<ResolvedRange> out;
    for (const auto& [address, handle] : buffers_by_address_) {
        const TrackedBuffer& b = buffers_.at(handle);
        if (b.flags & VK_BUFFER_CREATE_SPARSE_BINDING_BIT) {
            append_host_mapped_sparse_runs(b, out);
            continue;
        }
        auto mem = memories_.find(b.memory);
        if (b.memory == 0 || mem == memories_.end() || !mem->second.host_base) continue;
        if (b.memory_offset > mem->second.size || b.size > mem->second.size - b.memory_offset)
            continue;
        ResolvedRange r;
        r.buffer = b;
        r.memory = mem->second;
        r.host = mem->second.host_base + b.memory_offset;
        out.push_back(r);
    }
    return out;
}

std::vector<std::pair<VkDeviceAddress, VkDeviceAddress>> DeviceMemoryMap::address_ranges_in(
    uint64_t memory) const {
    std::lock_guard lock(mutex_);
    std::vector<std::pair<VkDeviceAddress, VkDeviceAddress>> out;
    for (const auto& [address, handle] : buffers_by_address_) {
        const TrackedBuffer& b = buffers_.at(handle);
        if (b.memory == memory) out.emplace_back(address, address + b.size);
        auto pages = sparse_pages_.find(handle);
        if (pages == sparse_pages_.end()) continue;
        for (const auto& [first, page] : pages->second)
            if (page.memory == memory) out.emplace_back(address + first, address + page.end);
    }
    return out;
}

void DeviceMemoryMap::append_host_mapped_sparse_runs(const TrackedBuffer& b,
                                                     std::vector<ResolvedRange>& out) const {
    auto pages = sparse_pages_.find(b.handle);
    if (pages == sparse_pages_.end()) return;
    // Pages that follow each other in the buffer and in one allocation make one run: a served
    // build writes an object across a page boundary of a buffer bound in one piece.
    auto emit = [&](VkDeviceSize begin, VkDeviceSize end, uint64_t memory,
                    VkDeviceSize memory_offset) {
        auto mem = memories_.find(memory);
        if (mem == memories_.end() || !mem->second.host_base) return;
        if (memory_offset > mem->second.size || end - begin > mem->second.size - memory_offset)
            return;
        ResolvedRange r;
        r.buffer = b;
        r.buffer.address = b.address + begin;
        r.buffer.size = end - begin;
        r.buffer.memory = memory;
        r.buffer.memory_offset = memory_offset;
        r.memory = mem->second;
        r.host = mem->second.host_base + memory_offset;
        out.push_back(r);
    };
    bool open = false;
    VkDeviceSize begin = 0, end = 0, memory_offset = 0;
    uint64_t memory = 0;
    for (const auto& [offset, page] : pages->second) {
        if (open && offset == end && page.memory == memory &&
            page.memory_offset == memory_offset + (end - begin)) {
            end = page.end;
            continue;
        }
        if (open) emit(begin, end, memory, memory_offset);
        open = true;
        begin = offset;
        end = page.end;
        memory = page.memory;
        memory_offset = page.memory_offset;
    }
    if (open) emit(begin, end, memory, memory_offset);
}

std::vector<TrackedBuffer> DeviceMemoryMap::unmapped_addressed_buffers(
    VkBufferUsageFlags usage_mask) const {
    std::lock_guard lock(mutex_);
    std::vector<TrackedBuffer> out;
    for (const auto& [address, handle] : buffers_by_address_) {
        const TrackedBuffer& b = buffers_.at(handle);
        auto mem = memories_.find(b.memory);
        if (b.memory == 0 || mem == memories_.end() || mem->second.host_base ||
            !(b.usage & usage_mask))
            continue;
        if (b.memory_offset > mem->second.size || b.size > mem->second.size - b.memory_offset)
            continue;
        out.push_back(b);
    }
    return out;
}

}  // namespace clastrace::capture
