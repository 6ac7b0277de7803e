#include "clastrace/engine/memory_image.h"

#include <cinttypes>
#include <cstdio>
#include <limits>

namespace clastrace::engine {

namespace {
std::string hex(uint64_t v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "0x%" PRIx64, v);
  return buf;
}
}  // namespace

void MemoryImage::fault(uint64_t address, uint64_t size, FieldRef where, const std::string& what) {
  MemoryFault f;
  f.address = address;
  f.size = size;
  f.field = where.field ? where.field : "";
  f.op_index = where.op_index;
  f.message = what + " (address " + hex(address) + ", " + std::to_string(size) + " bytes, field " +
              (f.field.empty() ? std::string("?") : f.field) + ", op " + std::to_string(where.op_index) + ")";
  throw f;
}

MemoryRegion& MemoryImage::add_region(uint64_t base, uint64_t size, VkBufferUsageFlags usage, std::string label) {
  FieldRef where{"add_region", -1};
  if (size == 0) fault(base, size, where, "memory region of size 0");
  // A region may end exactly at 2^64 (its last byte is 2^64 - 1), never beyond.
  const uint64_t last = base + (size - 1);
  if (last < base) fault(base, size, where, "memory region wraps the 64-bit address space");
  auto next = regions_.lower_bound(base);
  if (next != regions_.end() && next->first <= last)
    fault(base, size, where, "memory region overlaps region '" + next->second.label + "' at " + hex(next->first));
  if (next != regions_.begin()) {
    auto prev = std::prev(next);
    if (prev->first + (prev->second.size - 1) >= base)
      fault(base, size, where, "memory region overlaps region '" + prev->second.label + "' at " + hex(prev->first));
  }
  if (size > std::numeric_limits<size_t>::max() / 2) fault(base, size, where, "memory region too large for this host");
  MemoryRegion r;
  r.base = base;
  r.size = size;
  r.usage = usage;
  r.label = std::move(label);
  r.bytes.assign(static_cast<size_t>(size), std::byte{0});
  return regions_.emplace(base, std::move(r)).first->second;
}

const MemoryRegion* MemoryImage::find_region(uint64_t address) const {
  auto it = regions_.upper_bound(address);
  if (it == regions_.begin()) return nullptr;
  --it;
  if (address - it->first < it->second.size) return &it->second;
  return nullptr;
}

MemoryRegion* MemoryImage::find_region(uint64_t address) {
  return const_cast<MemoryRegion*>(static_cast<const MemoryImage*>(this)->find_region(address));
}

std::span<const std::byte> MemoryImage::read_bytes(uint64_t address, uint64_t size, FieldRef where) const {
  const MemoryRegion* r = find_region(address);
  if (!r) fault(address, size, where, address == 0 ? "null device address read" : "read from an address outside every memory region");
  const uint64_t offset = address - r->base;
  if (size > r->size - offset)
    fault(address, size, where, "read runs off the end of region '" + r->label + "' [" + hex(r->base) + ", +" + std::to_string(r->size) + ")");
  return {r->bytes.data() + offset, static_cast<size_t>(size)};
}

std::span<std::byte> MemoryImage::write_bytes(uint64_t address, uint64_t size, FieldRef where) {
  MemoryRegion* r = find_region(address);
  if (!r) fault(address, size, where, address == 0 ? "null device address write" : "write to an address outside every memory region");
  const uint64_t offset = address - r->base;
  if (size > r->size - offset)
    fault(address, size, where, "write runs off the end of region '" + r->label + "' [" + hex(r->base) + ", +" + std::to_string(r->size) + ")");
  return {r->bytes.data() + offset, static_cast<size_t>(size)};
}

namespace {
uint64_t element_address(uint64_t start, uint64_t stride, uint64_t index, uint64_t element_size, uint64_t bound,
                         FieldRef where) {
  const uint64_t step = stride == 0 ? element_size : stride;
  if (step != 0 && index > (std::numeric_limits<uint64_t>::max() - element_size) / step)
    MemoryImage::fault(start, element_size, where, "strided array offset overflows 64 bits at element " + std::to_string(index));
  const uint64_t offset = index * step;
  if (bound != 0 && offset + element_size > bound)
    MemoryImage::fault(start, element_size, where,
                       "element " + std::to_string(index) + " lies beyond the strided region's size " + std::to_string(bound));
  const uint64_t address = start + offset;
  if (address < start) MemoryImage::fault(start, element_size, where, "strided array address wraps 2^64 at element " + std::to_string(index));
  return address;
}
}  // namespace

uint64_t MemoryImage::strided_address(const VkStridedDeviceAddressRegionKHR& region, uint64_t index, uint64_t element_size,
                                      FieldRef where) {
  return element_address(region.deviceAddress, region.stride, index, element_size, region.size, where);
}

uint64_t MemoryImage::strided_address(const VkStridedDeviceAddressNV& array, uint64_t index, uint64_t element_size,
                                      FieldRef where) {
  return element_address(array.startAddress, array.strideInBytes, index, element_size, 0, where);
}

std::span<const std::byte> MemoryImage::read_array(uint64_t address, uint64_t count, uint64_t stride, uint64_t element_size,
                                                   FieldRef where) const {
  if (count == 0) return {};
  const uint64_t step = stride == 0 ? element_size : stride;
  const uint64_t last = element_address(address, step, count - 1, element_size, 0, where);
  (void)last;
  const uint64_t total = (count - 1) * step + element_size;  // no overflow: checked above
  return read_bytes(address, total, where);
}

}  // namespace clastrace::engine
