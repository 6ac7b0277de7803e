// SPDX-License-Identifier: Apache-2.0
// The address space a replay sees: every bound buffer as a region of one MemoryImage,
// buffer/offset pairs resolved to device addresses, and the byte ranges the engine built
// objects into (captured snapshots never overwrite those: in a driver trace they hold the
// driver's bytes, which the engine cannot read).
#pragma once

#include <clastrace/engine/memory_image.h>
#include <clastrace/replay/sync_types.h>

#include "laid_index.h"

#include <algorithm>

#include <cstdint>
#include <map>
#include <optional>
#include <span>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

namespace clastrace::replay::detail {

class ReplayMemory : public AddressResolver {
public:
    // Bytes the image may hold in all. Regions are sparse (engine::RegionBytes): binding a
    // buffer reserves address space only, and the budget counts the pages written.
    explicit ReplayMemory(uint64_t budget_bytes = 8ull << 30) : budget_(budget_bytes) {
        image_.set_resident_limit(budget_bytes);
        image_.log_writes(&writes_);
    }
    // The image logs its writes into writes_: a copy would log into the original's.
    ReplayMemory(const ReplayMemory&) = delete;
    ReplayMemory& operator=(const ReplayMemory&) = delete;

    void create_buffer(uint64_t buffer, uint64_t size, uint64_t usage);
    // Binds and adds the buffer's region. Buffers without a device address get one: the
    // memory object's base (learned from an addressed buffer bound to it) plus the offset,
    // or a private range above kPrivateBase, so aliasing through memory still overlaps.
    void bind_buffer(uint64_t buffer, uint64_t memory, uint64_t memory_offset,
                     uint64_t device_address);
    void bind_object(uint64_t object, uint64_t memory, uint64_t memory_offset);  // NV AS
    // One VkSparseMemoryBind of a sparse buffer (vkQueueBindSparse), in queue order: from now
    // on [resource_offset, + size) of the buffer is memory `memory` at `memory_offset` (0:
    // unbound), replacing what was bound there. The buffer's first bind places it: at
    // `device_address`, or in a private range when it has none. Its bytes stay at its own
    // addresses in the image (the engine reads and writes there); resolve() tells the
    // synchronization model which memory each address reaches.
    void bind_sparse(uint64_t buffer, uint64_t device_address, uint64_t resource_offset,
                     uint64_t size, uint64_t memory, uint64_t memory_offset);
    // AddressResolver: a sparse buffer's bound parts resolve to their memory object's base
    // (the device address of a buffer bound to it at offset 0, as bind_buffer learns it) plus
    // the memory offset, so an access through another buffer aliasing that memory meets them.
    bool resolve(AddressRange range, std::vector<ResolvedRange>* parts) override;
    // The sparse buffer holding `address` and the offset in it, if one does.
    std::optional<std::pair<uint64_t, uint64_t>> sparse_buffer_at(uint64_t address) const;
    // What a sparse bind is checked against: a created buffer's size, and its address once
    // placed (bound, or a sparse buffer's first bind); nullopt for a buffer never created.
    struct BufferExtent {
        uint64_t size = 0;
        std::optional<uint64_t> address;
    };
    std::optional<BufferExtent> buffer_extent(uint64_t buffer) const;
    // Whether [address, address + size) meets a placed sparse buffer's addresses.
    bool meets_sparse_buffer(uint64_t address, uint64_t size) const;
    // Bound parts of all sparse buffers (each resolve() walks those under its range).
    size_t sparse_page_count() const { return sparse_pages_.size(); }
    void create_object(uint64_t object, uint64_t buffer, uint64_t offset, uint64_t size,
                       uint64_t requirement);
    void object_requirement(uint64_t object, uint64_t size) { object_size_[object] = size; }
    // vkDestroyBuffer: its region and bytes go (unless another live buffer overlaps them),
    // and the engine no longer owns bytes there. Returns the range it had, if bound.
    std::optional<AddressRange> destroy_buffer(uint64_t buffer);
    void destroy_object(uint64_t object);
    // vkAllocateMemory: the allocation's size, for memory_range().
    void allocate_memory(uint64_t memory, uint64_t size) { memory_objects_[memory].size = size; }
    void free_memory(uint64_t memory) { memory_objects_.erase(memory); }
    // The device addresses of the whole allocation, once its size and its base (the address of
    // its first byte, as a buffer bound to it said) are known.
    std::optional<AddressRange> memory_range(uint64_t memory) const {
        auto it = memory_objects_.find(memory);
        if (it == memory_objects_.end() || !it->second.base || !it->second.size)
            return std::nullopt;
        return AddressRange{*it->second.base, *it->second.base + *it->second.size};
    }

    // [offset, offset + size) of `buffer` as device addresses (VK_WHOLE_SIZE: to the end).
    std::optional<AddressRange> buffer_range(uint64_t buffer, uint64_t offset, uint64_t size) const;
    std::optional<AddressRange> object_range(uint64_t object) const;
    // Where a snapshot lies: its address, or (a format without one) its buffer's plus offset.
    // Inline: every snapshot of every command asks, and mostly the address is there.
    std::optional<uint64_t> snapshot_address(uint64_t buffer, uint64_t offset,
                                             uint64_t address) const {
        if (address != 0) return address;
        return buffer_snapshot_address(buffer, offset);
    }

    // Writes `bytes` at `address`, leaving engine-built object bytes alone. False when no
    // region holds the range.
    bool lay_in(uint64_t address, std::span<const uint8_t> bytes);
    // The same for the bytes of content `hash`, skipped when that content was the last laid in
    // at `address` and no write has met its bytes since: laying it again would change no byte
    // (the engine's objects and a driver BVH's kept bytes inside it hold what they held then).
    bool lay_in(uint64_t address, std::span<const uint8_t> bytes, uint64_t hash);
    // Whether that skip applies without the content's bytes: `hash` was the content last laid in
    // at `address`, no write has met it since and no driver BVH is marked over it (whose kept
    // bytes a report counts). Its size in *size.
    // Inline: every input snapshot asks, and mostly the answer is yes.
    bool holds_laid_content(uint64_t address, uint64_t hash, uint64_t* size) {
        forget_written();
        const LaidIndex::Entry* laid = laid_index_.find(address);
        if (!laid || laid->hash != hash) return false;
        if (!driver_bvh_.empty() && meets_driver_bvh({address, laid->end})) return false;
        *size = laid->end - address;
        return true;
    }
    // Plain write (copies, fills, updates): also ends engine ownership of those bytes.
    bool write(uint64_t address, std::span<const uint8_t> bytes);
    bool read(uint64_t address, uint64_t size, std::vector<uint8_t>* out) const;
    // vkCmdCopyBuffer's bytes, from one place of the image to another, as write() does (an
    // overlap, which the application may not ask for, copies as if through a buffer between).
    // False when no region holds either range (nothing is written then).
    bool copy(uint64_t from, uint64_t size, uint64_t to);
    void mark_engine_object(AddressRange range);
    // A served traceable cluster BLAS (CmdBuildClusterAccelerationStructureIndirect.driver_bvh):
    // the capture's memory there holds the driver's BVH, replay's holds the engine's object.
    // Plain writes (write(), fill(), a destroyed buffer) end the mark.
    void mark_driver_bvh(AddressRange range);
    // The bytes to lay in for `captured` (at `address`): the image's own wherever a driver BVH
    // is marked, so laying them in keeps the engine's bytes. Those are a copy in *edited, made
    // only when a mark is met; else `captured` itself. With the marked ranges met (whole) and
    // the bytes kept.
    struct KeptDriverBvh {
        std::span<const uint8_t> to_lay_in;
        std::vector<AddressRange> ranges;
        uint64_t bytes = 0;
    };
    KeptDriverBvh keep_driver_bvh(uint64_t address, std::span<const uint8_t> captured,
                                  std::vector<uint8_t>* edited) const;
    // An explicit-destination cluster BLAS: the bytes its build may have written (its
    // dstSizesArray room), which a driver's rays through it may read. Plain writes end the mark.
    void mark_cluster_blas_span(AddressRange range);
    // The marked span that starts at `address`, if any.
    std::optional<AddressRange> cluster_blas_span(uint64_t address) const;
    // The first byte of [begin, end) that a bound buffer holds but no bound buffer created
    // with a bit of `usage` (or with unknown usage, 0) holds; nullopt when there is none.
    // Aliased buffers count each on their own (VUIDs 12305/12307 take any buffer over a byte).
    std::optional<uint64_t> first_without_usage(uint64_t begin, uint64_t end, uint64_t usage) const;
    uint64_t aliased_buffers() const { return aliased_buffers_; }
    // Buffers left out of the image because they would exceed the address-space limit (handle, size).
    const std::vector<std::pair<uint64_t, uint64_t>>& over_budget() const { return over_budget_; }
    // Writes refused because the image would hold more than the budget.
    uint64_t writes_over_budget() const { return image_.resident_limit_faults(); }
    // The most bytes the image held at once, as sampled by note_peak() (after each submission batch).
    uint64_t peak_resident_bytes() const { return peak_; }
    void note_peak() { peak_ = std::max(peak_, image_.resident_bytes()); }
    // Address space all regions may span: far beyond any real trace, below what a 47-bit
    // user address space can reserve.
    static constexpr uint64_t kReservedLimit = 1ull << 44;
    // Fills [address, address + size) with a repeated 32-bit value in place (vkCmdFillBuffer).
    bool fill(uint64_t address, uint64_t size, uint32_t value);

    // Writing through the image is logged (lay_in): the log is met with the laid contents here
    // first (and in write, copy and fill), so it holds the writes of one command at most,
    // however long no lay-in comes.
    engine::MemoryImage& image() {
        forget_written();
        return image_;
    }
    const engine::MemoryImage& image() const { return image_; }
    // Regions added so far: a build read ahead whose buffers were not placed yet may be
    // planned once this changed (Replay's pending runs).
    uint64_t regions_added() const { return regions_added_; }

    static constexpr uint64_t kPrivateBase = 0xF000'0000'0000'0000ull;

private:
    struct Buffer {
        uint64_t size = 0;
        uint64_t usage = 0;
        uint64_t address = 0;
        bool bound = false;
    };
    struct Object {
        uint64_t address = 0;
        uint64_t size = 0;
        bool bound = false;
    };
    void unmark(AddressRange range);
    std::optional<uint64_t> buffer_snapshot_address(uint64_t buffer, uint64_t offset) const;
    // Whether a driver BVH's mark meets `range`.
    bool meets_driver_bvh(AddressRange range) const;
    // The contents laid in that a write met (range, or each write the image logged) no longer
    // lie there.
    void forget_laid(AddressRange range);
    // Inline: called at every lay-in and image() hand-out, mostly with nothing logged since.
    void forget_written() {
        if (!writes_.empty()) forget_written_runs();
    }
    void forget_written_runs();
    void unindex(uint64_t buffer);
    // Adds the region (an alias of an existing one is served by it); false when over the limit.
    bool add_region(uint64_t address, uint64_t size, uint64_t usage, const std::string& label);
    uint64_t memory_base(uint64_t memory);
    void place_sparse(uint64_t buffer, uint64_t device_address);
    void forget_sparse(uint64_t buffer, AddressRange range);

    engine::MemoryImage image_;
    std::unordered_map<uint64_t, Buffer> buffers_;
    std::multimap<uint64_t, uint64_t> bound_at_;  // address -> bound buffer handle
    uint64_t largest_bound_ = 0;                  // size of the largest buffer ever bound
    std::unordered_map<uint64_t, Object> objects_;
    std::unordered_map<uint64_t, uint64_t> object_size_;
    // A memory object: its base (learned from an addressed buffer bound to it, or a private
    // range memory_base() gave it) and its size (vkAllocateMemory), each once known.
    struct MemoryObject {
        std::optional<uint64_t> base;
        std::optional<uint64_t> size;
    };
    std::unordered_map<uint64_t, MemoryObject> memory_objects_;
    struct SparseSpan {  // a placed sparse buffer's addresses
        uint64_t end = 0;
        uint64_t buffer = 0;
    };
    std::map<uint64_t, SparseSpan> sparse_spans_;  // begin -> span, disjoint
    struct SparsePage {                            // a bound part of a sparse buffer
        uint64_t end = 0;
        uint64_t memory = 0;
        uint64_t memory_offset = 0;
    };
    std::map<uint64_t, SparsePage> sparse_pages_;  // begin address -> bound part, disjoint
    uint64_t next_private_ = kPrivateBase;
    uint64_t aliased_buffers_ = 0;
    std::map<uint64_t, uint64_t> engine_objects_;  // begin -> end, disjoint, merged
    AddressRange last_object_;  // the engine_objects_ range the last marked object joined
    std::map<uint64_t, uint64_t> driver_bvh_;          // begin -> end, disjoint
    std::map<uint64_t, uint64_t> cluster_blas_spans_;  // begin -> end, disjoint
    // The contents laid in and not met since: by first byte for the lookups (laid_index_), and
    // ordered (begin -> end, disjoint) for the overlap walks of forget_laid.
    LaidIndex laid_index_;
    std::map<uint64_t, uint64_t> laid_;
    std::vector<std::pair<uint64_t, uint64_t>> writes_;  // (address, size) not yet met with laid_
    uint64_t budget_;
    uint64_t peak_ = 0;
    uint64_t regions_added_ = 0;
    std::vector<std::pair<uint64_t, uint64_t>> over_budget_;
};

}  // namespace clastrace::replay::detail
