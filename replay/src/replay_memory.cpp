// SPDX-License-Identifier: Apache-2.0
#include "replay_memory.h"

#include <algorithm>
#include <new>
#include <cstdio>
#include <cstring>

namespace clastrace::replay::detail {

namespace {
constexpr uint64_t kWholeSize = ~0ull;
constexpr uint64_t kPrivateSpan =
    1ull << 40;  // address space per memory object without a device address
}  // namespace

void ReplayMemory::create_buffer(uint64_t buffer, uint64_t size, uint64_t usage) {
    unindex(buffer);
    buffers_[buffer] = Buffer{size, usage, 0, false};
}

void ReplayMemory::unindex(uint64_t buffer) {
    auto it = buffers_.find(buffer);
    if (it == buffers_.end() || !it->second.bound) return;
    auto [first, last] = bound_at_.equal_range(it->second.address);
    for (auto at = first; at != last; ++at) {
        if (at->second == buffer) {
            bound_at_.erase(at);
            break;
        }
    }
}

std::optional<uint64_t> ReplayMemory::first_without_usage(uint64_t begin, uint64_t end,
                                                          uint64_t usage) const {
    // The part of each bound buffer over [begin, end), and whether it has the usage.
    struct Part {
        AddressRange range;
        bool allowed = false;
    };
    auto each_part = [&](auto&& visit) {
        for (auto it = bound_at_.lower_bound(begin > largest_bound_ ? begin - largest_bound_ : 0);
             it != bound_at_.end() && it->first < end; ++it) {
            const Buffer& b = buffers_.at(it->second);
            const uint64_t b_end = b.address + b.size < b.address ? UINT64_MAX : b.address + b.size;
            if (b_end <= begin || b.size == 0) continue;
            visit(Part{{std::max(begin, b.address), std::min(end, b_end)},
                       b.usage == 0 || (b.usage & usage) != 0});
        }
    };
    // Mostly one buffer holds the range (each op's element of a usage check): the answer is
    // its first byte or none, without the lists below.
    size_t parts = 0;
    Part only;
    each_part([&](const Part& p) {
        if (parts++ == 0) only = p;
    });
    if (parts <= 1) {
        if (parts == 0 || only.allowed) return std::nullopt;
        return only.range.begin;
    }
    std::vector<AddressRange> held, allowed;
    each_part([&](const Part& p) {
        held.push_back(p.range);
        if (p.allowed) allowed.push_back(p.range);
    });
    auto by_begin = [](const AddressRange& a, const AddressRange& b) { return a.begin < b.begin; };
    std::sort(allowed.begin(), allowed.end(), by_begin);
    std::vector<AddressRange> merged;  // the allowed bytes as disjoint, non-adjacent ranges
    for (const AddressRange& r : allowed) {
        if (!merged.empty() && r.begin <= merged.back().end)
            merged.back().end = std::max(merged.back().end, r.end);
        else
            merged.push_back(r);
    }
    std::optional<uint64_t> first;
    for (const AddressRange& h : held) {
        uint64_t at = h.begin;
        auto m = std::partition_point(merged.begin(), merged.end(),
                                      [&](const AddressRange& r) { return r.end <= at; });
        if (m != merged.end() && m->begin <= at) at = m->end;
        if (at < h.end && (!first || at < *first)) first = at;
    }
    return first;
}

uint64_t ReplayMemory::memory_base(uint64_t memory) {
    std::optional<uint64_t>& base = memory_objects_[memory].base;
    if (base) return *base;
    base = next_private_;
    next_private_ += kPrivateSpan;
    if (next_private_ < kPrivateBase)
        next_private_ = kPrivateBase;  // wrapped: reuse (aliasing at worst)
    return *base;
}

bool ReplayMemory::add_region(uint64_t address, uint64_t size, uint64_t usage,
                              const std::string& label) {
    if (size == 0 || address + size < address) return true;
    if (size > kReservedLimit - std::min(kReservedLimit, image_.reserved_bytes())) return false;
    try {
        image_.add_region(address, size, static_cast<VkBufferUsageFlags>(usage), label);
        ++regions_added_;
    } catch (const engine::MemoryFault&) {
        // Two buffers over the same bytes (aliasing): the first region serves both as far
        // as it reaches; the rest of this buffer stays outside the image. An address is
        // "allocated from a buffer created with" a usage (12304-12308) if any buffer over
        // it has that usage: the region takes this buffer's usage too (0 stays unknown).
        ++aliased_buffers_;
        if (engine::MemoryRegion* r = image_.find_region(address); r && r->usage != 0)
            r->usage |= static_cast<VkBufferUsageFlags>(usage);
    } catch (const std::bad_alloc&) {
        return false;
    }
    return true;
}

std::optional<AddressRange> ReplayMemory::destroy_buffer(uint64_t buffer) {
    auto it = buffers_.find(buffer);
    if (it == buffers_.end()) return std::nullopt;
    unindex(buffer);
    const Buffer b = it->second;
    buffers_.erase(it);
    if (!b.bound || b.size == 0 || b.address + b.size < b.address) return std::nullopt;
    const AddressRange range{b.address, b.address + b.size};
    // The region serving this buffer (its own, or the one it aliased) goes once no live
    // buffer overlaps it: another buffer over the same memory keeps seeing the bytes.
    if (const engine::MemoryRegion* region = image_.find_region(b.address)) {
        const uint64_t begin = region->base, end = region->base + region->size;
        bool shared = false;
        for (const auto& [handle, other] : buffers_)
            if (other.bound && other.address < end && begin < other.address + other.size)
                shared = true;
        if (!shared) {
            image_.remove_region(begin);
            forget_laid({begin, end});
        }
    }
    unmark(range);
    forget_sparse(buffer, range);
    return range;
}

void ReplayMemory::destroy_object(uint64_t object) {
    objects_.erase(object);
    object_size_.erase(object);
}

bool ReplayMemory::fill(uint64_t address, uint64_t size, uint32_t value) {
    forget_written();  // keeps the image's write log short (image())
    try {
        if (value == 0) {
            image_.zero_bytes(address, size,
                              {"vkCmdFillBuffer", -1});  // a cleared buffer costs no pages
        } else {
            std::span<std::byte> dst = image_.write_bytes(address, size, {"vkCmdFillBuffer", -1});
            for (uint64_t k = 0; k + 4 <= size; k += 4) std::memcpy(dst.data() + k, &value, 4);
        }
    } catch (const engine::MemoryFault&) {
        return false;
    }
    unmark({address, address + size});
    return true;
}

void ReplayMemory::bind_buffer(uint64_t buffer, uint64_t memory, uint64_t memory_offset,
                               uint64_t device_address) {
    unindex(buffer);
    Buffer& b = buffers_[buffer];
    if (device_address != 0) {
        b.address = device_address;
        if (memory != 0 && device_address >= memory_offset) {
            std::optional<uint64_t>& base = memory_objects_[memory].base;
            if (!base) base = device_address - memory_offset;
        }
    } else {
        b.address = memory_base(memory) + memory_offset;
    }
    b.bound = true;
    bound_at_.emplace(b.address, buffer);
    largest_bound_ = std::max(largest_bound_, b.size);
    char label[40];
    std::snprintf(label, sizeof label, "buffer 0x%llx", static_cast<unsigned long long>(buffer));
    if (!add_region(b.address, b.size, b.usage, label)) over_budget_.emplace_back(buffer, b.size);
}

void ReplayMemory::bind_object(uint64_t object, uint64_t memory, uint64_t memory_offset) {
    Object& o = objects_[object];
    o.address = memory_base(memory) + memory_offset;
    auto size = object_size_.find(object);
    if (size != object_size_.end()) o.size = size->second;
    o.bound = true;
}

void ReplayMemory::create_object(uint64_t object, uint64_t buffer, uint64_t offset, uint64_t size,
                                 uint64_t) {
    if (buffer == 0) return;  // NV objects are placed by bind_object
    if (auto r = buffer_range(buffer, offset, size ? size : kWholeSize)) {
        objects_[object] = Object{r->begin, r->end - r->begin, true};
    }
}

std::optional<AddressRange> ReplayMemory::buffer_range(uint64_t buffer, uint64_t offset,
                                                       uint64_t size) const {
    auto it = buffers_.find(buffer);
    if (it == buffers_.end() || !it->second.bound) return std::nullopt;
    const Buffer& b = it->second;
    if (offset > b.size) return std::nullopt;
    uint64_t n = size == kWholeSize ? b.size - offset : std::min(size, b.size - offset);
    return AddressRange{b.address + offset, b.address + offset + n};
}

std::optional<AddressRange> ReplayMemory::object_range(uint64_t object) const {
    auto it = objects_.find(object);
    if (it == objects_.end() || !it->second.bound) return std::nullopt;
    uint64_t size = it->second.size;
    if (size == 0) {
        auto s = object_size_.find(object);
        if (s == object_size_.end()) return std::nullopt;
        size = s->second;
    }
    return AddressRange{it->second.address, it->second.address + size};
}

std::optional<uint64_t> ReplayMemory::buffer_snapshot_address(uint64_t buffer,
                                                              uint64_t offset) const {
    auto it = buffers_.find(buffer);
    if (it == buffers_.end() || !it->second.bound) return std::nullopt;
    return it->second.address + offset;
}

bool ReplayMemory::lay_in(uint64_t address, std::span<const uint8_t> bytes) {
    if (bytes.empty()) return true;
    std::span<std::byte> dst;
    try {
        dst = image_.write_bytes(address, bytes.size(), {"snapshot", -1});
    } catch (const engine::MemoryFault&) {
        return false;
    }
    const uint64_t end = address + bytes.size();
    uint64_t cursor = address;
    auto it = engine_objects_.upper_bound(address);
    if (it != engine_objects_.begin()) --it;
    for (; it != engine_objects_.end() && it->first < end; ++it) {
        if (it->second <= cursor) continue;
        uint64_t skip_begin = std::max(it->first, cursor);
        if (skip_begin > cursor)
            std::memcpy(dst.data() + (cursor - address), bytes.data() + (cursor - address),
                        skip_begin - cursor);
        cursor = std::min(it->second, end);
    }
    if (cursor < end)
        std::memcpy(dst.data() + (cursor - address), bytes.data() + (cursor - address),
                    end - cursor);
    return true;
}

bool ReplayMemory::lay_in(uint64_t address, std::span<const uint8_t> bytes, uint64_t hash) {
    forget_written();
    const AddressRange range{address, address + bytes.size()};
    const LaidIndex::Entry* laid = laid_index_.find(address);
    if (laid && laid->end == range.end && laid->hash == hash) return true;
    if (!lay_in(address, bytes)) return false;
    writes_.clear();  // lay_in's own write
    if (range.empty()) return true;
    forget_laid(range);
    laid_.emplace(address, range.end);
    laid_index_.insert(address, range.end, hash);
    return true;
}

bool ReplayMemory::meets_driver_bvh(AddressRange range) const {
    auto mark = driver_bvh_.upper_bound(range.begin);
    if (mark != driver_bvh_.begin() && std::prev(mark)->second > range.begin) return true;
    return mark != driver_bvh_.end() && mark->first < range.end;
}

void ReplayMemory::forget_laid(AddressRange range) {
    auto it = laid_.upper_bound(range.begin);
    if (it != laid_.begin() && std::prev(it)->second > range.begin) --it;
    while (it != laid_.end() && it->first < range.end) {
        laid_index_.erase(it->first);
        it = laid_.erase(it);
    }
}

// A command's writes come in a few interleaved streams (a cluster build's objects, its address
// and size arrays, its scratch entries), each rising and taking turns: a write joins the open run
// it starts in or near, tried first the one after the run the last write joined, so a command
// costs a few forget_laid calls instead of one a write. A run also covers the bytes between its
// writes, which only costs those contents a lay-in again.
void ReplayMemory::forget_written_runs() {
    if (laid_.empty()) {
        writes_.clear();
        return;
    }
    constexpr size_t kRuns = 4;
    constexpr uint64_t kNear = 256;
    AddressRange runs[kRuns];
    size_t open = 0, next = 0, oldest = 0;
    auto joins = [&](size_t k, uint64_t begin) {
        return begin - runs[k].begin <= runs[k].end - runs[k].begin + kNear;  // (wraps below)
    };
    for (const auto& [address, size] : writes_) {
        const AddressRange w{address, address + size};  // logged writes lie in a region: no wrap
        size_t k = next;
        if (k >= open || !joins(k, w.begin))
            for (k = 0; k < open && !joins(k, w.begin);) ++k;
        if (k < open) {
            runs[k].end = std::max(runs[k].end, w.end);
            next = k + 1 < open ? k + 1 : 0;
            continue;
        }
        if (open < kRuns) {
            runs[open++] = w;
        } else {
            forget_laid(runs[oldest]);
            runs[oldest] = w;
            oldest = (oldest + 1) % kRuns;
        }
        next = 0;
    }
    for (size_t k = 0; k < open; ++k) forget_laid(runs[k]);
    writes_.clear();
}

bool ReplayMemory::write(uint64_t address, std::span<const uint8_t> bytes) {
    forget_written();  // keeps the image's write log short (image())
    if (bytes.empty()) return true;
    try {
        std::span<std::byte> dst = image_.write_bytes(address, bytes.size(), {"copy", -1});
        std::memcpy(dst.data(), bytes.data(), bytes.size());
    } catch (const engine::MemoryFault&) {
        return false;
    }
    unmark({address, address + bytes.size()});
    return true;
}

bool ReplayMemory::copy(uint64_t from, uint64_t size, uint64_t to) {
    forget_written();  // keeps the image's write log short (image())
    if (size == 0) return true;
    try {
        // A write never moves a region's bytes, so `src` stays valid across write_bytes.
        std::span<const std::byte> src = image_.read_bytes(from, size, {"replay", -1});
        std::span<std::byte> dst = image_.write_bytes(to, size, {"copy", -1});
        std::memmove(dst.data(), src.data(), size);
    } catch (const engine::MemoryFault&) {
        return false;
    }
    unmark({to, to + size});
    return true;
}

bool ReplayMemory::read(uint64_t address, uint64_t size, std::vector<uint8_t>* out) const {
    try {
        std::span<const std::byte> src = image_.read_bytes(address, size, {"replay", -1});
        out->resize(size);
        if (size) std::memcpy(out->data(), src.data(), size);
        return true;
    } catch (const engine::MemoryFault&) {
        return false;
    }
}

// Removes [range) from a set of disjoint ranges, cutting the ones it overlaps.
static void cut(std::map<uint64_t, uint64_t>& ranges, AddressRange range) {
    auto it = ranges.upper_bound(range.begin);
    if (it != ranges.begin()) --it;
    while (it != ranges.end() && it->first < range.end) {
        uint64_t b = it->first, e = it->second;
        if (e <= range.begin) {
            ++it;
            continue;
        }
        it = ranges.erase(it);
        if (b < range.begin) ranges.emplace(b, range.begin);
        if (e > range.end) it = ranges.emplace(range.end, e).first;
    }
}

// Adds `range` to a set of disjoint ranges kept merged (no two overlap or touch), for a set
// read only as bytes (lay_in skips them). Each op of a cluster build marks its object, mostly
// inside the objects built there the frame before, which are one range by then: marking is one
// lookup (it was ~750 instructions an op keeping each object its own range, and ~1,600 before).
// Returns the range of the set that holds `range` now.
static AddressRange unite(std::map<uint64_t, uint64_t>& ranges, AddressRange range) {
    auto it = ranges.upper_bound(range.begin);
    if (it != ranges.begin()) {
        const auto before = std::prev(it);
        if (before->second >= range.end) return {before->first, before->second};  // inside
        if (before->second >= range.begin) {  // meets or touches it: grows over the rest
            uint64_t end = range.end;
            while (it != ranges.end() && it->first <= end) {
                end = std::max(end, it->second);
                it = ranges.erase(it);
            }
            before->second = end;
            return {before->first, end};
        }
    }
    uint64_t end = range.end;
    std::map<uint64_t, uint64_t>::node_type spare;  // a node the range swallows, reused
    while (it != ranges.end() && it->first <= end) {
        end = std::max(end, it->second);
        const auto next = std::next(it);
        if (spare.empty())
            spare = ranges.extract(it);
        else
            ranges.erase(it);
        it = next;
    }
    if (spare.empty()) {
        ranges.emplace_hint(it, range.begin, end);
        return {range.begin, end};
    }
    spare.key() = range.begin;
    spare.mapped() = end;
    ranges.insert(it, std::move(spare));
    return {range.begin, end};
}

void ReplayMemory::unmark(AddressRange range) {
    forget_laid(range);  // (zero_bytes, which fill uses, is not logged as a write)
    cut(engine_objects_, range);
    last_object_ = {};
    cut(driver_bvh_, range);
    cut(cluster_blas_spans_, range);
}

void ReplayMemory::mark_cluster_blas_span(AddressRange range) {
    if (range.empty()) return;
    cut(cluster_blas_spans_, range);
    cluster_blas_spans_.emplace(range.begin, range.end);
}

std::optional<AddressRange> ReplayMemory::cluster_blas_span(uint64_t address) const {
    auto it = cluster_blas_spans_.find(address);
    if (it == cluster_blas_spans_.end()) return std::nullopt;
    return AddressRange{it->first, it->second};
}

void ReplayMemory::mark_driver_bvh(AddressRange range) {
    if (range.empty()) return;
    cut(driver_bvh_, range);
    driver_bvh_.emplace(range.begin, range.end);
}

ReplayMemory::KeptDriverBvh ReplayMemory::keep_driver_bvh(uint64_t address,
                                                          std::span<const uint8_t> captured,
                                                          std::vector<uint8_t>* edited) const {
    KeptDriverBvh kept{captured, {}, 0};
    if (driver_bvh_.empty()) return kept;
    const uint64_t end = address + captured.size();
    auto it = driver_bvh_.upper_bound(address);
    if (it != driver_bvh_.begin()) --it;
    std::vector<uint8_t> current;
    for (; it != driver_bvh_.end() && it->first < end; ++it) {
        const uint64_t b = std::max(it->first, address), e = std::min(it->second, end);
        if (b >= e || !read(b, e - b, &current)) continue;
        if (kept.ranges.empty()) {  // the first mark met: the captured bytes are copied
            edited->assign(captured.begin(), captured.end());
            kept.to_lay_in = *edited;
        }
        std::memcpy(edited->data() + (b - address), current.data(), e - b);
        kept.ranges.push_back({it->first, it->second});
        kept.bytes += e - b;
    }
    return kept;
}

void ReplayMemory::mark_engine_object(AddressRange range) {
    if (range.empty()) return;
    // Mostly inside the range the object before joined (last frame's objects, merged): then
    // neither set changes.
    if (driver_bvh_.empty() && range.begin >= last_object_.begin && range.end <= last_object_.end)
        return;
    // (A cluster BLAS span stays: the engine's object is written inside it.)
    cut(driver_bvh_, range);
    last_object_ = unite(engine_objects_, range);
}

}  // namespace clastrace::replay::detail

namespace clastrace::replay::detail {

void ReplayMemory::place_sparse(uint64_t buffer, uint64_t device_address) {
    Buffer& b = buffers_[buffer];
    if (b.bound) return;
    if (device_address != 0) {
        b.address = device_address;
    } else {
        b.address = next_private_;  // its own range: only resolve() makes it meet memory
        next_private_ += kPrivateSpan;
    }
    b.bound = true;
    bound_at_.emplace(b.address, buffer);
    largest_bound_ = std::max(largest_bound_, b.size);
    char label[48];
    std::snprintf(label, sizeof label, "sparse buffer 0x%llx",
                  static_cast<unsigned long long>(buffer));
    if (!add_region(b.address, b.size, b.usage, label)) over_budget_.emplace_back(buffer, b.size);
    if (b.size != 0 && b.address + b.size > b.address)
        sparse_spans_[b.address] = SparseSpan{b.address + b.size, buffer};
}

void ReplayMemory::bind_sparse(uint64_t buffer, uint64_t device_address, uint64_t resource_offset,
                               uint64_t size, uint64_t memory, uint64_t memory_offset) {
    place_sparse(buffer, device_address);
    const Buffer& b = buffers_[buffer];
    if (resource_offset >= b.size || !sparse_spans_.count(b.address)) return;
    const uint64_t begin = b.address + resource_offset;
    const uint64_t end = begin + std::min(size, b.size - resource_offset);
    // A rebind replaces whatever was bound over its range: cut those parts back to the rest.
    auto it = sparse_pages_.upper_bound(begin);
    if (it != sparse_pages_.begin() && std::prev(it)->second.end > begin) --it;
    while (it != sparse_pages_.end() && it->first < end) {
        const uint64_t page_begin = it->first;
        const SparsePage page = it->second;
        it = sparse_pages_.erase(it);
        if (page_begin < begin)
            sparse_pages_.emplace(page_begin, SparsePage{begin, page.memory, page.memory_offset});
        if (page.end > end)
            it = sparse_pages_
                     .emplace(end, SparsePage{page.end, page.memory,
                                              page.memory_offset + (end - page_begin)})
                     .first;
    }
    if (memory != 0) sparse_pages_.emplace(begin, SparsePage{end, memory, memory_offset});
}

void ReplayMemory::forget_sparse(uint64_t buffer, AddressRange range) {
    auto span = sparse_spans_.find(range.begin);
    if (span == sparse_spans_.end() || span->second.buffer != buffer) return;
    sparse_spans_.erase(span);
    sparse_pages_.erase(sparse_pages_.lower_bound(range.begin),
                        sparse_pages_.lower_bound(range.end));
}

bool ReplayMemory::resolve(AddressRange range, std::vector<ResolvedRange>* parts) {
    if (sparse_spans_.empty() || range.empty()) return false;
    auto span = sparse_spans_.upper_bound(range.begin);
    if (span != sparse_spans_.begin() && std::prev(span)->second.end > range.begin) --span;
    if (span == sparse_spans_.end() || span->first >= range.end) return false;
    parts->clear();
    uint64_t at = range.begin;
    for (; span != sparse_spans_.end() && span->first < range.end; ++span) {
        if (at < span->first) parts->push_back({{at, span->first}, true});
        at = std::max(at, span->first);
        const uint64_t span_end = std::min(span->second.end, range.end);
        auto page = sparse_pages_.upper_bound(at);
        if (page != sparse_pages_.begin() && std::prev(page)->second.end > at) --page;
        while (at < span_end) {
            if (page == sparse_pages_.end() || page->first >= span_end) {
                parts->push_back({{at, span_end}, false});
                break;
            }
            if (page->first > at) {
                parts->push_back({{at, page->first}, false});
                at = page->first;
            }
            const uint64_t part_end = std::min(page->second.end, span_end);
            const uint64_t base =
                memory_base(page->second.memory) + page->second.memory_offset + (at - page->first);
            parts->push_back({{base, base + (part_end - at)}, true});
            at = part_end;
            ++page;
        }
        at = span_end;
    }
    if (at < range.end) parts->push_back({{at, range.end}, true});
    return true;
}

std::optional<ReplayMemory::BufferExtent> ReplayMemory::buffer_extent(uint64_t buffer) const {
    auto it = buffers_.find(buffer);
    if (it == buffers_.end()) return std::nullopt;
    BufferExtent extent{it->second.size, std::nullopt};
    if (it->second.bound) extent.address = it->second.address;
    return extent;
}

bool ReplayMemory::meets_sparse_buffer(uint64_t address, uint64_t size) const {
    const uint64_t end = address + size;
    auto span = sparse_spans_.lower_bound(end);
    if (span == sparse_spans_.begin()) return false;
    --span;
    return span->second.end > address;
}

std::optional<std::pair<uint64_t, uint64_t>> ReplayMemory::sparse_buffer_at(
    uint64_t address) const {
    auto span = sparse_spans_.upper_bound(address);
    if (span == sparse_spans_.begin()) return std::nullopt;
    --span;
    if (address >= span->second.end) return std::nullopt;
    return std::pair{span->second.buffer, address - span->first};
}

}  // namespace clastrace::replay::detail
