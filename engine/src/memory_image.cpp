// SPDX-License-Identifier: Apache-2.0
#include "clastrace/engine/memory_image.h"
#include "clastrace/common/debug_assert.h"
#include "clastrace/common/hex.h"

#include <sys/mman.h>

#include <algorithm>
#include <cinttypes>
#include <cstdio>
#include <limits>
#include <cstdlib>
#include <new>

namespace clastrace::engine {

namespace {
using common::hex;

// The counted run at `run` is non-empty, ends by `page_count` and neither meets nor overlaps
// the runs beside it.
bool run_fits(const std::map<uint64_t, uint64_t>& runs,
              std::map<uint64_t, uint64_t>::const_iterator run, uint64_t page_count) {
    if (run->first >= run->second || run->second > page_count) return false;
    if (run != runs.begin() && std::prev(run)->second >= run->first) return false;
    const auto next = std::next(run);
    return next == runs.end() || run->second < next->first;
}

// The region keyed at `at` is keyed by its base, non-empty, inside 2^64 and clear of the
// regions beside it.
bool region_fits(const std::map<uint64_t, MemoryRegion>& regions,
                 std::map<uint64_t, MemoryRegion>::const_iterator at) {
    const MemoryRegion& r = at->second;
    if (at->first != r.base || r.size == 0 || r.base + (r.size - 1) < r.base ||
        r.bytes.size() != r.size)
        return false;
    if (at != regions.begin()) {
        const MemoryRegion& prev = std::prev(at)->second;
        if (prev.base + (prev.size - 1) >= r.base) return false;
    }
    const auto next = std::next(at);
    return next == regions.end() || r.base + (r.size - 1) < next->first;
}
}  // namespace

// ------------------------------------------------------------------------ RegionBytes

RegionBytes::RegionBytes(uint64_t size) {
    if (size == 0) return;
    if (size > std::numeric_limits<uint64_t>::max() - kPageBytes) throw std::bad_alloc();
    const uint64_t mapped = (size + kPageBytes - 1) / kPageBytes * kPageBytes;
    if (mapped > std::numeric_limits<size_t>::max()) throw std::bad_alloc();
    // Private anonymous memory: the kernel maps a page on first write and reads of untouched
    // pages see its shared zero page, so address space is all a region costs up front.
    void* p = mmap(nullptr, static_cast<size_t>(mapped), PROT_READ | PROT_WRITE,
                   MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
    if (p == MAP_FAILED) {
        // Each mapping is one kernel VMA and their number is capped (vm.max_map_count, 65530
        // by default): a trace with that many live buffers still replays, its small ones held
        // densely on the heap and counted whole.
        if (mapped > kDenseFallbackBytes) throw std::bad_alloc();
        p = std::calloc(static_cast<size_t>(mapped), 1);
        if (!p) throw std::bad_alloc();
        dense_ = true;
        touched_.emplace(0, mapped / kPageBytes);
        resident_ = mapped;
    }
    data_ = static_cast<std::byte*>(p);
    size_ = size;
    mapped_ = mapped;
}

void RegionBytes::release() {
    if (data_ && dense_)
        std::free(data_);
    else if (data_)
        munmap(data_, static_cast<size_t>(mapped_));
    data_ = nullptr;
    dense_ = false;
    size_ = mapped_ = resident_ = 0;
    touched_.clear();
}

RegionBytes::~RegionBytes() { release(); }

RegionBytes::RegionBytes(RegionBytes&& other) noexcept
    : dense_(other.dense_),
      data_(other.data_),
      size_(other.size_),
      mapped_(other.mapped_),
      resident_(other.resident_),
      touched_(std::move(other.touched_)) {
    other.dense_ = false;
    other.data_ = nullptr;
    other.size_ = other.mapped_ = other.resident_ = 0;
    other.touched_.clear();
}

RegionBytes& RegionBytes::operator=(RegionBytes&& other) noexcept {
    if (this == &other) return *this;
    release();
    dense_ = other.dense_;
    data_ = other.data_;
    size_ = other.size_;
    mapped_ = other.mapped_;
    resident_ = other.resident_;
    touched_ = std::move(other.touched_);
    other.dense_ = false;
    other.data_ = nullptr;
    other.size_ = other.mapped_ = other.resident_ = 0;
    other.touched_.clear();
    return *this;
}

RegionBytes::RegionBytes(const RegionBytes& other) : RegionBytes(other.size_) {
    for (const auto& [first, last] : other.touched_) {
        const uint64_t begin = first * kPageBytes, end = std::min(last * kPageBytes, size_);
        std::memcpy(data_ + begin, other.data_ + begin, static_cast<size_t>(end - begin));
    }
    if (dense_) return;  // a dense copy counts itself whole
    touched_ = other.touched_;
    resident_ = other.resident_;
}

RegionBytes& RegionBytes::operator=(const RegionBytes& other) {
    if (this != &other) *this = RegionBytes(other);
    return *this;
}

uint64_t RegionBytes::untouched_bytes(uint64_t offset, uint64_t size) const {
    if (size == 0 || offset >= size_) return 0;
    uint64_t first = offset / kPageBytes;
    const uint64_t last = (std::min(offset + size, size_) + kPageBytes - 1) / kPageBytes;
    uint64_t missing = 0;
    auto it = touched_.upper_bound(first);
    if (it != touched_.begin()) {
        auto prev = std::prev(it);
        if (prev->second > first) first = std::min(prev->second, last);
    }
    for (; first < last; ++it) {
        const uint64_t run_begin = it == touched_.end() ? last : std::min(it->first, last);
        missing += run_begin - first;
        if (it == touched_.end()) break;
        first = std::min(std::max(first, it->second), last);
    }
    return missing * kPageBytes;
}

uint64_t RegionBytes::touch(uint64_t offset, uint64_t size) {
    if (size == 0 || offset >= size_) return 0;
    uint64_t first = offset / kPageBytes;
    uint64_t last = (std::min(offset + size, size_) + kPageBytes - 1) / kPageBytes;
    // Fast path: already inside one counted run.
    auto it = touched_.upper_bound(first);
    if (it != touched_.begin()) {
        auto prev = std::prev(it);
        if (prev->second >= last) return 0;
        if (prev->second >= first) it = prev;  // overlaps or is adjacent: merge
    }
    uint64_t covered = 0;
    while (it != touched_.end() && it->first <= last) {
        first = std::min(first, it->first);
        last = std::max(last, it->second);
        covered += it->second - it->first;
        it = touched_.erase(it);
    }
    const auto run = touched_.emplace(first, last).first;
    const uint64_t added = (last - first - covered) * kPageBytes;
    resident_ += added;
    CLASTRACE_DEBUG_ASSERT(run_fits(touched_, run, mapped_ / kPageBytes) && resident_ <= mapped_);
    return added;
}

uint64_t RegionBytes::zero(uint64_t offset, uint64_t size) {
    if (size == 0 || offset >= size_) return 0;
    const uint64_t end = std::min(offset + size, size_);
    // Whole pages inside go back to the OS (they read as zeros again); the edges are cleared.
    uint64_t page_begin = (offset + kPageBytes - 1) / kPageBytes, page_end = end / kPageBytes;
    if (end == size_) page_end = mapped_ / kPageBytes;  // the region's tail page is ours alone
    // Pages never counted already read as zeros: only counted ones need clearing.
    auto clear = [&](uint64_t b, uint64_t e) {
        if (b >= e ||
            untouched_bytes(b, e - b) == ((e - 1) / kPageBytes - b / kPageBytes + 1) * kPageBytes)
            return;
        std::memset(data_ + b, 0, static_cast<size_t>(e - b));
        touch(b, e - b);
    };
    if (page_begin >= page_end || dense_) {  // heap memory is not ours to give back to the OS
        clear(offset, end);
        return 0;
    }
    const uint64_t head = page_begin * kPageBytes, tail = std::min(page_end * kPageBytes, size_);
    clear(offset, std::min(head, end));
    clear(std::max(tail, offset), end);
    madvise(data_ + head, static_cast<size_t>((page_end - page_begin) * kPageBytes), MADV_DONTNEED);
    // Stop counting [page_begin, page_end).
    uint64_t released = 0;
    auto it = touched_.upper_bound(page_begin);
    if (it != touched_.begin()) --it;
    while (it != touched_.end() && it->first < page_end) {
        const uint64_t b = it->first, e = it->second;
        if (e <= page_begin) {
            ++it;
            continue;
        }
        it = touched_.erase(it);
        released += std::min(e, page_end) - std::max(b, page_begin);
        if (b < page_begin) touched_.emplace(b, page_begin);
        if (e > page_end) it = touched_.emplace(page_end, e).first;
    }
    resident_ -= released * kPageBytes;
    CLASTRACE_DEBUG_ASSERT(resident_ <= mapped_);
    return released * kPageBytes;
}

bool RegionBytes::invariants_hold() const {
    uint64_t pages = 0;
    for (auto run = touched_.begin(); run != touched_.end(); ++run) {
        if (!run_fits(touched_, run, mapped_ / kPageBytes)) return false;
        pages += run->second - run->first;
    }
    return resident_ == pages * kPageBytes && (!dense_ || resident_ == mapped_);
}

// ------------------------------------------------------------------------ MemoryImage

void MemoryImage::fault(uint64_t address, uint64_t size, FieldRef where, const std::string& what) {
    MemoryFault f;
    f.address = address;
    f.size = size;
    f.field = where.field ? where.field : "";
    f.op_index = where.op_index;
    f.message = what + " (address " + hex(address) + ", " + std::to_string(size) +
                " bytes, field " + (f.field.empty() ? std::string("?") : f.field) + ", op " +
                std::to_string(where.op_index) + ")";
    throw f;
}

MemoryRegion& MemoryImage::add_region(uint64_t base, uint64_t size, VkBufferUsageFlags usage,
                                      std::string label) {
    return add_region(base, size, usage, std::move(label), RegionBytes());
}

std::vector<RegionBytes> MemoryImage::release_storage() {
    std::vector<RegionBytes> storage;
    storage.reserve(regions_.size());
    for (auto& [base, region] : regions_) storage.push_back(std::move(region.bytes));
    regions_.clear();
    reserved_ = written_ = 0;
    return storage;
}

MemoryRegion& MemoryImage::add_region(uint64_t base, uint64_t size, VkBufferUsageFlags usage,
                                      std::string label, RegionBytes&& storage) {
    FieldRef where{"add_region", -1};
    if (size == 0) fault(base, size, where, "memory region of size 0");
    // A region may end exactly at 2^64 (its last byte is 2^64 - 1), never beyond.
    const uint64_t last = base + (size - 1);
    if (last < base) fault(base, size, where, "memory region wraps the 64-bit address space");
    auto next = regions_.lower_bound(base);
    if (next != regions_.end() && next->first <= last)
        fault(base, size, where,
              "memory region overlaps region '" + next->second.label + "' at " + hex(next->first));
    if (next != regions_.begin()) {
        auto prev = std::prev(next);
        if (prev->first + (prev->second.size - 1) >= base)
            fault(base, size, where,
                  "memory region overlaps region '" + prev->second.label + "' at " +
                      hex(prev->first));
    }
    if (size > std::numeric_limits<size_t>::max() / 2)
        fault(base, size, where, "memory region too large for this host");
    MemoryRegion r;
    r.base = base;
    r.size = size;
    r.usage = usage;
    r.label = std::move(label);
    const bool reused = storage.size() == size;
    r.bytes = reused ? std::move(storage) : RegionBytes(size);
    reserved_ += size;
    if (reused || r.bytes.dense())
        written_ += r.bytes.resident_bytes();  // counted already / held whole from the start
    const auto added = regions_.emplace(base, std::move(r)).first;
    CLASTRACE_DEBUG_ASSERT(region_fits(regions_, added));
    return added->second;
}

bool MemoryImage::invariants_hold() const {
    uint64_t reserved = 0;
    for (auto at = regions_.begin(); at != regions_.end(); ++at) {
        if (!region_fits(regions_, at) || !at->second.bytes.invariants_hold()) return false;
        reserved += at->second.size;
    }
    return reserved == reserved_;
}

bool MemoryImage::remove_region(uint64_t base, RegionBytes* storage) {
    auto it = regions_.find(base);
    if (it == regions_.end()) return false;
    reserved_ -= it->second.size;
    written_ -= std::min(written_, it->second.bytes.resident_bytes());
    if (storage) *storage = std::move(it->second.bytes);
    regions_.erase(it);
    return true;
}

uint64_t MemoryImage::resident_bytes() const {
    uint64_t total = 0;
    for (const auto& [base, r] : regions_) total += r.bytes.resident_bytes();
    return total;
}

void MemoryImage::zero_bytes(uint64_t address, uint64_t size, FieldRef where) {
    MemoryRegion* r = &region_holding(address, size, where, "write");
    const uint64_t offset = address - r->base;
    const uint64_t before = r->bytes.resident_bytes();
    r->bytes.zero(offset, size);
    const uint64_t after = r->bytes.resident_bytes();
    if (after < before)
        written_ -= std::min(written_, before - after);
    else
        written_ += after - before;
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

const MemoryRegion& MemoryImage::region_holding(uint64_t address, uint64_t size, FieldRef where,
                                                const char* access) const {
    const MemoryRegion* r = find_region(address);
    if (r && r->holds(address, size)) return *r;
    const std::string what = access;
    if (!r)
        fault(address, size, where,
              address == 0 ? "null device address " + what
                           : what + (what == "read" ? " from" : " to") +
                                 " an address outside every memory region");
    fault(address, size, where,
          what + " runs off the end of region '" + r->label + "' [" + hex(r->base) + ", +" +
              std::to_string(r->size) + ")");
}

MemoryRegion& MemoryImage::region_holding(uint64_t address, uint64_t size, FieldRef where,
                                          const char* access) {
    return const_cast<MemoryRegion&>(
        static_cast<const MemoryImage*>(this)->region_holding(address, size, where, access));
}

std::span<const std::byte> MemoryImage::read_bytes(uint64_t address, uint64_t size,
                                                   FieldRef where) const {
    const MemoryRegion* r = &region_holding(address, size, where, "read");
    const uint64_t offset = address - r->base;
    return {r->bytes.data() + offset, static_cast<size_t>(size)};
}

std::span<std::byte> MemoryImage::write_bytes(uint64_t address, uint64_t size, FieldRef where) {
    MemoryRegion* r = &region_holding(address, size, where, "write");
    const uint64_t offset = address - r->base;
    if (resident_limit_ != ~0ull) {
        const uint64_t added = r->bytes.untouched_bytes(offset, size);
        if (added > 0 && written_ + added > resident_limit_) {
            ++resident_limit_faults_;
            fault(address, size, where,
                  "write would take the memory image past its limit of " +
                      std::to_string(resident_limit_) + " resident bytes (" +
                      std::to_string(written_) + " held)");
        }
    }
    uint64_t added = 0;
    std::byte* bytes = r->bytes.write_at(offset, size, &added);
    written_ += added;
    if (write_log_) write_log_->emplace_back(address, size);
    return {bytes, static_cast<size_t>(size)};
}

namespace {
uint64_t element_address(uint64_t start, uint64_t stride, uint64_t index, uint64_t element_size,
                         uint64_t bound, FieldRef where) {
    const uint64_t step = stride == 0 ? element_size : stride;
    if (step != 0 && index > (std::numeric_limits<uint64_t>::max() - element_size) / step)
        MemoryImage::fault(start, element_size, where,
                           "strided array offset overflows 64 bits at element " +
                               std::to_string(index));
    const uint64_t offset = index * step;
    if (bound != 0 && offset + element_size > bound)
        MemoryImage::fault(start, element_size, where,
                           "element " + std::to_string(index) +
                               " lies beyond the strided region's size " + std::to_string(bound));
    const uint64_t address = start + offset;
    if (address < start)
        MemoryImage::fault(start, element_size, where,
                           "strided array address wraps 2^64 at element " + std::to_string(index));
    return address;
}
}  // namespace

uint64_t MemoryImage::strided_address(const VkStridedDeviceAddressRegionKHR& region, uint64_t index,
                                      uint64_t element_size, FieldRef where) {
    return element_address(region.deviceAddress, region.stride, index, element_size, region.size,
                           where);
}

uint64_t MemoryImage::strided_address(const VkStridedDeviceAddressNV& array, uint64_t index,
                                      uint64_t element_size, FieldRef where) {
    return element_address(array.startAddress, array.strideInBytes, index, element_size, 0, where);
}

std::span<const std::byte> MemoryImage::read_array(uint64_t address, uint64_t count,
                                                   uint64_t stride, uint64_t element_size,
                                                   FieldRef where) const {
    if (count == 0) return {};
    const uint64_t step = stride == 0 ? element_size : stride;
    const uint64_t last = element_address(address, step, count - 1, element_size, 0, where);
    (void)last;
    const uint64_t total = (count - 1) * step + element_size;  // no overflow: checked above
    return read_bytes(address, total, where);
}

}  // namespace clastrace::engine
