// SPDX-License-Identifier: Apache-2.0
// MemoryImage: the device address space a replay sees, as sparse regions of bytes.
//
// Every engine input is read through it and every output written through it, so a
// hostile address, size or stride becomes a MemoryFault that names the address, the
// field it came from and the op index, never undefined behaviour.
//
// A region costs only the pages written: its bytes are reserved address space that the
// OS backs on first write (untouched pages read as zeros without being allocated), so a
// 1 GiB buffer whose trace references 1 MiB costs about 1 MiB, and spans that cross
// pages stay contiguous (no copying, no span invalidated by a later access).
#pragma once

#include "clastrace/vk_cluster_abi.h"

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <exception>
#include <map>
#include <memory>
#include <span>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

namespace clastrace::engine {

// Where an access comes from: shown in every fault and finding.
struct FieldRef {
    const char* field = "";  // e.g. "srcInfosArray[3].vertexBuffer"
    int64_t op_index = -1;   // index of the op in its command, -1 when none
};

// The bytes of one region, zero until written. Reading never allocates. Writing through
// touch() (what MemoryImage::write_bytes does) counts the pages it covers; the raw
// non-const accessors (data(), begin(), operator[]) give write access without a range, so
// data()/begin() count the whole region and operator[] its byte's page.
class RegionBytes {
public:
    static constexpr uint64_t kPageBytes =
        4096;  // accounting unit (the OS page on x86-64 and arm64 Linux)

    RegionBytes() = default;
    // Reserves `size` bytes of zeros; throws std::bad_alloc when the address space cannot be had.
    explicit RegionBytes(uint64_t size);
    ~RegionBytes();
    RegionBytes(RegionBytes&& other) noexcept;
    RegionBytes& operator=(RegionBytes&& other) noexcept;
    RegionBytes(const RegionBytes& other);  // copies the touched pages only
    RegionBytes& operator=(const RegionBytes& other);

    size_t size() const { return size_; }
    bool empty() const { return size_ == 0; }
    const std::byte* data() const { return data_; }
    std::byte* data() {
        touch(0, size_);
        return data_;
    }
    const std::byte* begin() const { return data_; }
    const std::byte* end() const { return data_ + size_; }
    std::byte* begin() { return data(); }
    std::byte* end() { return data_ + size_; }
    const std::byte& operator[](size_t i) const { return data_[i]; }
    std::byte& operator[](size_t i) {
        touch(i, 1);
        return data_[i];
    }
    operator std::vector<std::byte>() const { return {begin(), end()}; }

    // [offset, offset + size) for writing: counts its pages (adding the bytes newly counted
    // to *added when given) and returns its first byte.
    std::byte* write_at(uint64_t offset, uint64_t size, uint64_t* added = nullptr) {
        const uint64_t n = touch(offset, size);
        if (added) *added += n;
        return data_ + offset;
    }
    // Counts the pages of [offset, offset + size). Returns the bytes newly counted.
    uint64_t touch(uint64_t offset, uint64_t size);
    // Bytes of [offset, offset + size) in pages not counted yet (what touch() would add).
    uint64_t untouched_bytes(uint64_t offset, uint64_t size) const;
    // Zeros [offset, offset + size); whole pages inside go back to the OS and stop counting.
    // Returns the bytes no longer counted.
    uint64_t zero(uint64_t offset, uint64_t size);
    // Bytes in counted pages: what the region costs.
    uint64_t resident_bytes() const { return resident_; }
    // True when the region lives on the heap, wholly counted: the OS refused another mapping
    // (vm.max_map_count) and the region was small enough to hold densely.
    bool dense() const { return dense_; }
    static constexpr uint64_t kDenseFallbackBytes = 1ull << 20;

    // The counted runs are non-empty, disjoint, not adjacent and inside the region, and
    // resident_bytes() is their sum. O(runs): for tests; touch() and zero() check the runs they
    // change when debug checks are on (clastrace/common/debug_assert.h).
    bool invariants_hold() const;

private:
    void release();
    bool dense_ = false;
    std::byte* data_ = nullptr;
    uint64_t size_ = 0;
    uint64_t mapped_ = 0;  // size_ rounded up to whole pages
    uint64_t resident_ = 0;
    std::map<uint64_t, uint64_t>
        touched_;  // first page -> one past the last, disjoint, not adjacent
};

struct MemoryRegion {
    uint64_t base = 0;
    uint64_t size = 0;
    VkBufferUsageFlags usage = 0;
    std::string label;
    RegionBytes bytes;

    // Whether all of [address, address + length) lies inside the region.
    bool holds(uint64_t address, uint64_t length) const {
        return address - base < size && length <= size - (address - base);
    }
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
    MemoryRegion& add_region(uint64_t base, uint64_t size, VkBufferUsageFlags usage,
                             std::string label);
    // The same over `storage` when it holds exactly `size` bytes (bytes another image gave back
    // through release_storage): the region starts with those bytes as they are, for a caller
    // that overwrites every one of them; otherwise zero-filled as above. Reuse saves a fresh
    // mapping's page faults and its unmapping.
    MemoryRegion& add_region(uint64_t base, uint64_t size, VkBufferUsageFlags usage,
                             std::string label, RegionBytes&& storage);
    // Empties the image and hands back each region's bytes, for add_region to reuse.
    std::vector<RegionBytes> release_storage();

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

    // Forgets the region based at `base` and gives its pages back (a destroyed buffer), or,
    // with `storage`, hands its bytes there for add_region to reuse. False when no region
    // starts there.
    bool remove_region(uint64_t base, RegionBytes* storage = nullptr);
    // Zeros [address, address + size) inside one region (MemoryFault otherwise), giving whole
    // pages back: clearing memory never costs memory.
    void zero_bytes(uint64_t address, uint64_t size, FieldRef where);

    // Bytes the image holds: the counted pages of every region (see RegionBytes).
    uint64_t resident_bytes() const;
    // Bytes of address space its regions span (what a dense image would allocate).
    uint64_t reserved_bytes() const { return reserved_; }
    // write_bytes faults ("memory image limit") instead of counting pages beyond `bytes` in
    // all; the limit counts pages first written through write_bytes.
    void set_resident_limit(uint64_t bytes) { resident_limit_ = bytes; }
    uint64_t resident_limit_faults() const { return resident_limit_faults_; }
    // Whether write_bytes may count `bytes` more bytes without passing the limit.
    bool within_resident_limit(uint64_t bytes) const {
        return resident_limit_ == ~0ull ||
               (bytes <= resident_limit_ && written_ <= resident_limit_ - bytes);
    }
    // From now on write_bytes appends each (address, size) it hands out to *log (nullptr:
    // none): replay runs a command on an image of its own and copies exactly these bytes over.
    void log_writes(std::vector<std::pair<uint64_t, uint64_t>>* log) { write_log_ = log; }

    [[noreturn]] static void fault(uint64_t address, uint64_t size, FieldRef where,
                                   const std::string& what);

    // Regions are keyed by their base, non-empty, inside 2^64, disjoint, hold bytes of their size
    // (each with its own invariants), and reserved_bytes() is the sum of their sizes. O(regions):
    // for tests; add_region checks the region it adds when debug checks are on.
    bool invariants_hold() const;

private:
    // The region holding all of [address, address + size), or a fault naming the access
    // ("read" or "write") and why it does not fit.
    const MemoryRegion& region_holding(uint64_t address, uint64_t size, FieldRef where,
                                       const char* access) const;
    MemoryRegion& region_holding(uint64_t address, uint64_t size, FieldRef where,
                                 const char* access);

    std::map<uint64_t, MemoryRegion> regions_;  // keyed by base
    uint64_t reserved_ = 0;
    uint64_t written_ = 0;  // pages counted through write_bytes, for the limit
    uint64_t resident_limit_ = ~0ull;
    uint64_t resident_limit_faults_ = 0;
    std::vector<std::pair<uint64_t, uint64_t>>* write_log_ = nullptr;
};

}  // namespace clastrace::engine
