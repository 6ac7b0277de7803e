#include "clastrace/capture/device_memory_map.h"
#include "clastrace/common/hex.h"

#include <cstdio>
#include <cstring>

namespace clastrace::capture {
namespace {

using common::hex;

void eraseAddress(std::multimap<VkDeviceAddress, uint64_t>& byAddress, VkDeviceAddress address, uint64_t buffer) {
  auto [first, last] = byAddress.equal_range(address);
  for (auto it = first; it != last; ++it) {
    if (it->second == buffer) {
      byAddress.erase(it);
      return;
    }
  }
}

}  // namespace

void DeviceMemoryMap::addMemory(const TrackedMemory& memory) {
  std::lock_guard lock(mutex_);
  memories_[memory.handle] = memory;
}

void DeviceMemoryMap::removeMemory(uint64_t handle) {
  std::lock_guard lock(mutex_);
  memories_.erase(handle);
}

std::optional<TrackedMemory> DeviceMemoryMap::memory(uint64_t handle) const {
  std::lock_guard lock(mutex_);
  auto it = memories_.find(handle);
  if (it == memories_.end()) return std::nullopt;
  return it->second;
}

void DeviceMemoryMap::addBuffer(const TrackedBuffer& buffer) {
  std::lock_guard lock(mutex_);
  buffers_[buffer.handle] = buffer;
}

void DeviceMemoryMap::bindBuffer(uint64_t buffer, uint64_t memory, VkDeviceSize offset) {
  std::lock_guard lock(mutex_);
  auto it = buffers_.find(buffer);
  if (it == buffers_.end()) return;
  it->second.memory = memory;
  it->second.memoryOffset = offset;
}

void DeviceMemoryMap::setBufferAddress(uint64_t buffer, VkDeviceAddress address) {
  std::lock_guard lock(mutex_);
  auto it = buffers_.find(buffer);
  if (it == buffers_.end() || address == 0) return;
  if (it->second.address == address) return;
  if (it->second.address != 0) eraseAddress(buffersByAddress_, it->second.address, buffer);
  it->second.address = address;
  buffersByAddress_.emplace(address, buffer);
  if (it->second.size > largestAddressedBuffer_) largestAddressedBuffer_ = it->second.size;
}

void DeviceMemoryMap::removeBuffer(uint64_t handle) {
  std::lock_guard lock(mutex_);
  auto it = buffers_.find(handle);
  if (it == buffers_.end()) return;
  if (it->second.address != 0) eraseAddress(buffersByAddress_, it->second.address, handle);
  buffers_.erase(it);
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
  // Candidates start at or below `address`; none that starts more than the largest buffer's size
  // below it can reach it, which bounds the walk.
  auto it = buffersByAddress_.upper_bound(address);
  bool sawContainingStart = false;
  while (it != buffersByAddress_.begin()) {
    --it;
    if (address - it->first > largestAddressedBuffer_) break;
    const TrackedBuffer& b = buffers_.at(it->second);
    const VkDeviceSize offset = address - b.address;
    if (offset >= b.size && !(offset == b.size && size == 0)) continue;
    sawContainingStart = true;
    if (size > b.size - offset) continue;
    auto mem = memories_.find(b.memory);
    if (b.memory == 0 || mem == memories_.end()) continue;
    ResolvedRange r;
    r.buffer = b;
    r.offsetInBuffer = offset;
    r.memory = mem->second;
    if (mem->second.hostBase) r.host = mem->second.hostBase + b.memoryOffset + offset;
    return r;
  }
  why = sawContainingStart
            ? "address range " + hex(address) + "+" + hex(size) +
                  " runs past the end of its buffer or the buffer has no live memory bound"
            : "device address " + hex(address) + " is not inside any buffer whose address the application queried";
  return std::nullopt;
}

std::optional<ResolvedRange> DeviceMemoryMap::resolveBuffer(uint64_t buffer, VkDeviceSize offset, VkDeviceSize size,
                                                            std::string& why) const {
  std::lock_guard lock(mutex_);
  auto it = buffers_.find(buffer);
  if (it == buffers_.end()) {
    why = "buffer " + hex(buffer) + " is not a live buffer";
    return std::nullopt;
  }
  const TrackedBuffer& b = it->second;
  if (offset > b.size || size > b.size - offset) {
    why = "range " + hex(offset) + "+" + hex(size) + " runs past the end of buffer " + hex(buffer) + " (size " +
          hex(b.size) + ")";
    return std::nullopt;
  }
  auto mem = memories_.find(b.memory);
  if (b.memory == 0 || mem == memories_.end()) {
    why = "buffer " + hex(buffer) + " has no live memory bound";
    return std::nullopt;
  }
  ResolvedRange r;
  r.buffer = b;
  r.offsetInBuffer = offset;
  r.memory = mem->second;
  if (mem->second.hostBase) r.host = mem->second.hostBase + b.memoryOffset + offset;
  return r;
}

bool DeviceMemoryMap::read(VkDeviceAddress address, VkDeviceSize size, std::vector<uint8_t>& out,
                           std::string& why) const {
  auto range = resolve(address, size, why);
  if (!range) return false;
  if (!range->host) {
    why = "memory behind " + hex(address) + " is not host visible (staging copies are not implemented yet)";
    return false;
  }
  out.resize(size);
  if (size) std::memcpy(out.data(), range->host, size);
  return true;
}

std::vector<ResolvedRange> DeviceMemoryMap::hostAddressedBuffers() const {
  std::lock_guard lock(mutex_);
  std::vector<ResolvedRange> out;
  for (const auto& [address, handle] : buffersByAddress_) {
    const TrackedBuffer& b = buffers_.at(handle);
    auto mem = memories_.find(b.memory);
    if (b.memory == 0 || mem == memories_.end() || !mem->second.hostBase) continue;
    if (b.memoryOffset > mem->second.size || b.size > mem->second.size - b.memoryOffset) continue;
    ResolvedRange r;
    r.buffer = b;
    r.memory = mem->second;
    r.host = mem->second.hostBase + b.memoryOffset;
    out.push_back(r);
  }
  return out;
}

std::vector<TrackedBuffer> DeviceMemoryMap::unmappedAddressedBuffers(VkBufferUsageFlags usageMask) const {
  std::lock_guard lock(mutex_);
  std::vector<TrackedBuffer> out;
  for (const auto& [address, handle] : buffersByAddress_) {
    const TrackedBuffer& b = buffers_.at(handle);
    auto mem = memories_.find(b.memory);
    if (b.memory == 0 || mem == memories_.end() || mem->second.hostBase || !(b.usage & usageMask)) continue;
    if (b.memoryOffset > mem->second.size || b.size > mem->second.size - b.memoryOffset) continue;
    out.push_back(b);
  }
  return out;
}

}  // namespace clastrace::capture
