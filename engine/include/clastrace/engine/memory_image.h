// MemoryImage: the device address space a replay sees, as sparse regions of bytes.
//
// Every engine input is read through it and every output written through it, so a
// hostile address, size or stride becomes a MemoryFault that names the address, the
// field it came from and the op index, never undefined behaviour.
#ifndef CLASTRACE_ENGINE_MEMORY_IMAGE_H
#define CLASTRACE_ENGINE_MEMORY_IMAGE_H

#include "clastrace/vk_cluster_abi.h"

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <exception>
#include <map>
#include <span>
#include <string>
#include <type_traits>
#include <vector>

namespace clastrace::engine {

// Where an access comes from: shown in every fault and finding.
struct FieldRef {
  const char* field = "";  // e.g. "srcInfosArray[3].vertexBuffer"
  int64_t op_index = -1;   // index of the op in its command, -1 when none
};

struct MemoryRegion {
  uint64_t base = 0;
  uint64_t size = 0;
  VkBufferUsageFlags usage = 0;
  std::string label;
  std::vector<std::byte> bytes;
};

struct MemoryFault : std::exception {
  uint64_t address = 0;
  uint64_t size = 0;
  std::string field;
  int64_t op_index = -1;
  std::string message;  // complete sentence: rule broken, address, field, op index
  const char* what() const noexcept override { return message.c_str(); }
};

// Const members (find_region, read_bytes, read, read_array) only look up and may run
// concurrently from many threads; add_region and writes need exclusive access.
class MemoryImage {
 public:
  // Adds a zero-filled region. Throws MemoryFault on size 0, on base + size wrapping
  // 2^64, or on overlap with an existing region.
  MemoryRegion& add_region(uint64_t base, uint64_t size, VkBufferUsageFlags usage, std::string label);

  // The region containing `address`, or nullptr.
  const MemoryRegion* find_region(uint64_t address) const;
  MemoryRegion* find_region(uint64_t address);

  // The bytes [address, address + size) if they lie inside one region; MemoryFault
  // otherwise (no region, run off the end, or address + size wrapping 2^64).
  // size 0 is allowed and checks only that `address` lies in a region.
  std::span<const std::byte> read_bytes(uint64_t address, uint64_t size, FieldRef where) const;
  std::span<std::byte> write_bytes(uint64_t address, uint64_t size, FieldRef where);

  template <class T>
  T read(uint64_t address, FieldRef where) const {
    static_assert(std::is_trivially_copyable_v<T>);
    T value;
    std::memcpy(&value, read_bytes(address, sizeof(T), where).data(), sizeof(T));
    return value;
  }
  template <class T>
  void write(uint64_t address, const T& value, FieldRef where) {
    static_assert(std::is_trivially_copyable_v<T>);
    std::memcpy(write_bytes(address, sizeof(T), where).data(), &value, sizeof(T));
  }

  // Address of element `index` of a strided array; stride 0 means tightly packed
  // (element_size). Checks that the element lies inside region.size (when the region's
  // size is not 0) and that no arithmetic wraps. Does not check that memory exists
  // there: the read or write that follows does.
  static uint64_t strided_address(const VkStridedDeviceAddressRegionKHR& region, uint64_t index,
                                  uint64_t element_size, FieldRef where);
  static uint64_t strided_address(const VkStridedDeviceAddressNV& array, uint64_t index,
                                  uint64_t element_size, FieldRef where);

  // [first, first + count*stride) style span check for arrays the engine reads in bulk:
  // returns the bytes from `address` covering `count` elements of `element_size` at
  // `stride` (stride >= element_size or stride 0 = packed), or throws MemoryFault.
  std::span<const std::byte> read_array(uint64_t address, uint64_t count, uint64_t stride,
                                        uint64_t element_size, FieldRef where) const;

  const std::map<uint64_t, MemoryRegion>& regions() const { return regions_; }

  [[noreturn]] static void fault(uint64_t address, uint64_t size, FieldRef where, const std::string& what);

 private:
  std::map<uint64_t, MemoryRegion> regions_;  // keyed by base
};

}  // namespace clastrace::engine

#endif
