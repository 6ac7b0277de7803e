// SPDX-License-Identifier: Apache-2.0
// Transfer and compute commands: copies, fills and updates done in the replay's memory, and
// dispatches whose effect is what the capture saw them write.
#include "replayer_internal.h"

namespace clastrace::replay::detail {

// The field a possible device-address write names in hazard reports.
constexpr std::string_view kAnyDeviceAddress = "any memory through a buffer device address";
// The field of a write the exact mode saw (DeviceAddressWrites).
constexpr std::string_view kWrittenThroughAddress = "bytes written through a buffer device address";

void Replay::feed(const CommandRef& ref, const AddressRange& range, StageMask stage,
                  AccessMask access, bool write, std::string_view field) {
    if (!options_.check_hazards || range.empty()) return;
    ++report_.counts.accesses;
    sync_.record_access(ref, Access{range, stage, access, write, field});
}

void Replay::copy_buffer(const fbs::CmdCopyBuffer& copy, const CommandRef& ref,
                         const ReplayLocation& where) {
    ++report_.counts.copies;
    lay_in_snapshots(copy.inputs(), where);
    if (!copy.regions()) return;
    uint32_t i = 0;
    for (const fbs::BufferCopy* region : *copy.regions()) {
        auto src = memory_.buffer_range(copy.src_buffer(), region->src_offset(), region->size());
        auto dst = memory_.buffer_range(copy.dst_buffer(), region->dst_offset(), region->size());
        if (src && dst) {
            memory_.copy(src->begin, src->end - src->begin, dst->begin);
            if (options_.check_hazards) {
                report_.counts.accesses += 2;
                std::string src_field = "pRegions[" + std::to_string(i) + "].srcOffset";
                std::string dst_field = "pRegions[" + std::to_string(i) + "].dstOffset";
                sync_.record_copy(ref,
                                  Access{*src, VK_PIPELINE_STAGE_2_COPY_BIT,
                                         VK_ACCESS_2_TRANSFER_READ_BIT, false, src_field},
                                  Access{*dst, VK_PIPELINE_STAGE_2_COPY_BIT,
                                         VK_ACCESS_2_TRANSFER_WRITE_BIT, true, dst_field});
            }
        }
        ++i;
    }
}

void Replay::fill_buffer(const fbs::CmdFillBuffer& fill, const CommandRef& ref) {
    ++report_.counts.copies;
    auto range = memory_.buffer_range(fill.dst_buffer(), fill.dst_offset(), fill.size());
    if (!range) return;
    if (fill.size() == kWholeSize)
        range->end = range->begin + ((range->end - range->begin) & ~3ull);
    memory_.fill(range->begin, range->end - range->begin, fill.data());
    feed(ref, *range, VK_PIPELINE_STAGE_2_CLEAR_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT, true,
         "dstOffset");
}

void Replay::update_buffer(const fbs::CmdUpdateBuffer& update, const CommandRef& ref) {
    ++report_.counts.copies;
    const uint64_t size = update.data() ? update.data()->size() : 0;
    auto range = memory_.buffer_range(update.dst_buffer(), update.dst_offset(), size);
    if (!range || size == 0) return;
    memory_.write(range->begin,
                  std::span<const uint8_t>(update.data()->data(), range->end - range->begin));
    feed(ref, *range, VK_PIPELINE_STAGE_2_CLEAR_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT, true, "pData");
}

// Cheap mode for shaders that write through buffer device addresses: the trace does not say
// which bytes, so the dispatch is a possible writer of every device address. Later accesses
// that are not ordered after it get possible hazards (docs/replay.md, "Possible hazards").
void Replay::record_address_writes(const CommandRef& ref, uint64_t stages) {
    if (!options_.check_hazards) return;
    if (stages == 0) stages = VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT;  // a record that names none
    // One access in all of the stages: a barrier orders it only when its first scope holds every
    // one (sync_barrier_log.cpp), so a draw's mesh-shader write is not taken as ordered by a
    // barrier from the fragment stage alone, and the fix names all the stages.
    ++report_.counts.accesses;
    Access everywhere{AddressRange{1, ~0ull}, stages, VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT, true,
                      kAnyDeviceAddress};
    everywhere.possible = true;
    sync_.record_access(ref, everywhere);
}

void Replay::keep_exact_address_writes(const fbs::DeviceAddressWrites& writes) {
    std::vector<fbs::MemorySnapshot> kept;
    if (writes.writes())
        for (const fbs::MemorySnapshot* s : *writes.writes()) kept.push_back(*s);
    exact_address_writes_[{static_cast<uint32_t>(writes.submission()), writes.command_buffer(),
                           writes.command_index()}]
        .push_back(std::move(kept));
}

std::optional<std::vector<fbs::MemorySnapshot>> Replay::take_exact_address_writes(
    const CommandRef& ref) {
    if (exact_address_writes_.empty()) return std::nullopt;
    // By the command buffer that holds the dispatch and its index there (a secondary's own).
    const uint64_t handle = ref.secondary_handle ? ref.secondary_handle : ref.command_buffer_handle;
    const uint32_t index = ref.secondary_handle ? ref.secondary_command : ref.command;
    auto it = exact_address_writes_.find({ref.submission, handle, index});
    if (it == exact_address_writes_.end() || it->second.empty()) return std::nullopt;
    std::vector<fbs::MemorySnapshot> writes = std::move(it->second.front());
    it->second.pop_front();
    return writes;
}

// Exact mode: the bytes the capture saw the dispatch change are ordinary (certain) shader
// storage writes, and replay's memory takes their new bytes for the commands after it.
void Replay::record_exact_address_writes(const CommandRef& ref,
                                         const std::vector<fbs::MemorySnapshot>& writes) {
    std::vector<uint8_t> bytes;
    for (const fbs::MemorySnapshot& s : writes) {
        auto address = memory_.snapshot_address(s.buffer(), s.offset(), s.address());
        if (!address) continue;
        feed(ref, AddressRange{*address, *address + s.size()},
             VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT, true,
             kWrittenThroughAddress);
        if (contents(s.hash(), &bytes)) memory_.write(*address, bytes);
    }
}

void Replay::dispatch(const fbs::CmdDispatch& d, const CommandRef& ref,
                      const ReplayLocation& where) {
    lay_in_snapshots(d.inputs(), where);
    if (d.indirect_buffer() != 0) {
        if (auto r = memory_.buffer_range(d.indirect_buffer(), d.indirect_offset(), 12))
            feed(ref, *r, VK_PIPELINE_STAGE_2_DRAW_INDIRECT_BIT,
                 VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT, false, "indirect buffer");
    }
    if (d.storage_buffers()) {
        // Which bytes a shader writes is unknown: every bound storage range counts as read and written.
        for (const fbs::BoundBufferRange* b : *d.storage_buffers()) {
            std::optional<AddressRange> r;
            if (b->address() != 0 && b->range() != kWholeSize) {
                r = AddressRange{b->address(), b->address() + b->range()};
            } else {
                r = memory_.buffer_range(b->buffer(), b->offset(), b->range());
            }
            if (!r) continue;
            std::string field = "set " + std::to_string(b->set()) + " binding " +
                                std::to_string(b->binding()) + "[" +
                                std::to_string(b->array_element()) + "]";
            feed(ref, *r, VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT,
                 VK_ACCESS_2_SHADER_STORAGE_READ_BIT | VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT, true,
                 field);
        }
    }
    if (auto exact = take_exact_address_writes(ref))
        record_exact_address_writes(ref, *exact);
    else if (d.may_write_device_addresses())
        record_address_writes(ref, VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT);
    // The shader's effect is whatever the capture saw it write.
    if (d.outputs()) {
        std::vector<uint8_t> bytes;
        for (const fbs::MemorySnapshot* s : *d.outputs()) {
            auto address = memory_.snapshot_address(s->buffer(), s->offset(), s->address());
            if (address && contents(s->hash(), &bytes)) memory_.write(*address, bytes);
        }
    }
}

}  // namespace clastrace::replay::detail
