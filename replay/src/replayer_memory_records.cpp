// SPDX-License-Identifier: Apache-2.0
// Buffers and device memory: the replay's address space, the captured snapshots laid into it,
// and the host's writes to mapped memory.
#include "replayer_internal.h"

namespace clastrace::replay::detail {

// Buffers and device memory: the replay's address space, and the host's writes to mapped memory.
bool Replay::on_memory_record(fbs::RecordBody kind, const fbs::Record& r) {
    switch (kind) {
    case fbs::RecordBody::BufferCreate: {
        const auto* c = r.body_as_BufferCreate();
        memory_.create_buffer(c->buffer(), c->size(), c->usage());
        break;
    }
    case fbs::RecordBody::BufferBindMemory: {
        const auto* b = r.body_as_BufferBindMemory();
        memory_.bind_buffer(b->buffer(), b->memory(), b->memory_offset(), b->device_address());
        break;
    }
    case fbs::RecordBody::BufferDestroy:
        memory_freed(memory_.destroy_buffer(r.body_as_BufferDestroy()->buffer()));
        break;
    case fbs::RecordBody::MemoryAllocate: {
        const auto* a = r.body_as_MemoryAllocate();
        memory_.allocate_memory(a->memory(), a->size());
        break;
    }
    case fbs::RecordBody::MemoryFree: memory_.free_memory(r.body_as_MemoryFree()->memory()); break;
    case fbs::RecordBody::MemoryObservation:
        host_observation(*r.body_as_MemoryObservation());
        break;
    default: return false;
    }
    return true;
}

// A destroyed buffer's memory: nothing the replay keeps about those bytes can matter to a
// later command except accesses still in flight (the sync model keeps those).
void Replay::memory_freed(std::optional<AddressRange> range) {
    if (!range || range->empty()) return;
    directory_.forget(range->begin, range->end);
    auto inside = [&](uint64_t a) { return a >= range->begin && a < range->end; };
    std::erase_if(translation_.rebuilt, inside);
    std::erase_if(translation_.rebuilt_at,
                  [&](const auto& e) { return inside(e.first) || inside(e.second); });
    std::erase_if(translation_.translated_cells, [&](const auto& e) { return inside(e.first); });
    if (options_.check_hazards) sync_.memory_freed(*range);
}

void Replay::lay_in_snapshots(const traces::SnapshotVector* snapshots,
                              const ReplayLocation& where) {
    if (!snapshots) return;
    std::vector<uint8_t> edited;
    RecentContents::Bytes held_contents;
    for (const fbs::MemorySnapshot* s : *snapshots) {
        std::optional<uint64_t> address =
            memory_.snapshot_address(s->buffer(), s->offset(), s->address());
        // The reader's answer for a content it answered once is the same bytes (they hash to
        // the key), so a content lying where it was laid needs neither reading nor laying.
        uint64_t laid_size = 0;
        if (address && memory_.holds_laid_content(*address, s->hash(), &laid_size)) {
            ++report_.counts.snapshots_applied;
            report_.counts.snapshot_bytes += laid_size;
            continue;
        }
        const uint64_t refused = memory_.writes_over_budget();
        std::span<const uint8_t> bytes;
        const bool held = address && contents_view(s->hash(), &bytes, &held_contents);
        if (held) {
            const ReplayMemory::KeptDriverBvh kept =
                memory_.keep_driver_bvh(*address, bytes, &edited);
            report_.counts.driver_bvh_bytes_kept += kept.bytes;
            bytes = kept.to_lay_in;
        }
        if (!held || !memory_.lay_in(*address, bytes, s->hash())) {
            ++report_.counts.snapshots_outside_memory;
            if (memory_.writes_over_budget() != refused)
                continue;  // named once, by the budget finding
            add_finding(
                {"CLASTRACE-replay-snapshot-outside-memory",
                 "captured snapshot of " + std::to_string(s->size()) + " bytes at buffer " +
                     detail::hex(s->buffer()) + " offset " + std::to_string(s->offset()) +
                     " address " + detail::hex(s->address()) +
                     " lies in no bound buffer (or its contents are missing): not laid into memory",
                 FindingSource::kReplay, where, -1, s->address()});
            continue;
        }
        ++report_.counts.snapshots_applied;
        report_.counts.snapshot_bytes += bytes.size();
    }
}

void Replay::host_observation(const fbs::MemoryObservation& observation) {
    if (!observation.snapshots()) return;
    CommandRef ref{next_submission_, 0, 0, host_ops_++, "host write (mapped memory)"};
    // Reason 4: the capture saw the command read bytes the host changed after vkQueueSubmit, so
    // the image holds them already; the whole range is the host's write (capture/README.md).
    constexpr uint32_t kReadByCommand = 4;
    const bool read_by_command = observation.reason() == kReadByCommand;
    std::vector<uint8_t> edited, before;
    RecentContents::Bytes held_contents;
    for (const fbs::MemorySnapshot* s : *observation.snapshots()) {
        std::optional<uint64_t> address =
            memory_.snapshot_address(s->buffer(), s->offset(), s->address());
        std::span<const uint8_t> captured;
        if (!address || !contents_view(s->hash(), &captured, &held_contents)) {
            ++report_.counts.snapshots_outside_memory;
            continue;
        }
        // The capture saw the driver's BVH of a traceable cluster BLAS change: not the host's
        // write, and replay keeps the engine's object there.
        const ReplayMemory::KeptDriverBvh kept =
            memory_.keep_driver_bvh(*address, captured, &edited);
        const std::span<const uint8_t> bytes = kept.to_lay_in;
        report_.counts.driver_bvh_bytes_kept += kept.bytes;
        // A capture may observe mapped memory the host did not touch: only bytes that
        // changed count as a host write (unchanged ones would be false WAR/WAW hazards).
        AddressRange written{*address, *address + bytes.size()};
        if (!read_by_command && memory_.read(*address, bytes.size(), &before)) {
            size_t first = 0, last = bytes.size();
            while (first < last && bytes[first] == before[first]) ++first;
            while (last > first && bytes[last - 1] == before[last - 1]) --last;
            written = {*address + first, *address + last};
        }
        if (!memory_.write(*address, bytes)) {
            ++report_.counts.snapshots_outside_memory;
            continue;
        }
        for (const AddressRange& range : kept.ranges) memory_.mark_driver_bvh(range);
        ++report_.counts.snapshots_applied;
        report_.counts.snapshot_bytes += bytes.size();
        if (options_.check_hazards && !written.empty()) {
            ++report_.counts.accesses;
            sync_.host_access(ref, Access{written, VK_PIPELINE_STAGE_2_HOST_BIT,
                                          VK_ACCESS_2_HOST_WRITE_BIT, true, "mapped memory"});
        }
    }
}

}  // namespace clastrace::replay::detail
