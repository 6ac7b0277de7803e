// SPDX-License-Identifier: Apache-2.0
// SyncModel's address map: accesses recorded into the address segments they cover, each
// segment checked against what it held.
#include "sync_model_internal.h"

#include <algorithm>
#include <iterator>

namespace clastrace::replay {

void SyncModel::State::record(const Record& b, bool deserialize, std::vector<Finding>* collect) {
    ++stats.accesses;
    const uint64_t begin = b.range.begin, end = b.range.end;
    if (end <= begin) return;
    std::vector<Finding> found;
    if (!found_index.empty()) found_index.clear();  // clear() would wipe every bucket each time
    const Later later{&b, b.queue, deserialize};
    // A possible write leaves each segment's certain write and reads in place, so the segments
    // it covers stay apart.
    segments.update(
        begin, end, b.is_write && !b.possible,
        [&](Segment& fresh, uint64_t, uint64_t) {
            if (b.possible)
                fresh.possible_write = b;
            else if (b.is_write)
                fresh.write = b;
            else
                fresh.reads.push_back(b);
        },
        [&](Segment& seg, uint64_t seg_begin, uint64_t seg_end) {
            check_and_update(seg, seg_begin, seg_end, later, found);
        });
    if (collect)
        collect->insert(collect->end(), std::make_move_iterator(found.begin()),
                        std::make_move_iterator(found.end()));
    else
        for (const Finding& f : found) emit(f, b);
    stats.segments = segments.size();
    stats.peak_segments = std::max<uint64_t>(stats.peak_segments, segments.size());
}

void SyncModel::State::check_and_update(Segment& seg, uint64_t seg_begin, uint64_t seg_end,
                                        const Later& later, std::vector<Finding>& found) {
    const Record& b = *later.record;
    if (b.is_write) {
        bool any_read = false;
        for (Record& r : seg.reads) {
            if (r.tag == b.tag) continue;
            // A read the host saw complete orders nothing and hides nothing: sweeps drop
            // such reads lazily, so they must count as already gone.
            if (r.queue != kHostSlot && r.tag < queues[r.queue].complete) continue;
            any_read = true;
            if (auto fix = unordered(r, later, false, seg_begin, seg_end))
                note(found,
                     later.deserialize ? HazardClass::kDeserializeInUse
                                       : HazardClass::kWriteAfterRead,
                     r, b, *fix, seg_begin, seg_end);
        }
        // Cheap mode's possible writes meet reads only: a pass writing build inputs through
        // addresses and a barrier to the build's reads is the normal pattern, and the build's
        // own scratch and destination writes would otherwise be a possible WRITE-AFTER-WRITE in
        // every correct program (docs/replay.md, "Possible hazards").
        if (b.possible) {
            seg.possible_write = b;
            return;
        }
        if (!any_read && seg.write && seg.write->tag != b.tag) {
            if (auto fix = unordered(*seg.write, later, true, seg_begin, seg_end))
                note(found,
                     later.deserialize ? HazardClass::kDeserializeInUse
                                       : HazardClass::kWriteAfterWrite,
                     *seg.write, b, *fix, seg_begin, seg_end);
        }
        seg.write = b;
        seg.possible_write.reset();  // the bytes now hold this write's values
        seg.reads.clear();
        return;
    }
    auto check_write = [&](auto& w) {  // the certain or the possible write
        if (w && w->tag != b.tag) {
            if (auto fix = unordered(*w, later, true, seg_begin, seg_end))
                note(found, HazardClass::kReadAfterWrite, *w, b, *fix, seg_begin, seg_end);
        }
    };
    check_write(seg.write);
    check_write(seg.possible_write);
    // A host read is over when the call returns: it orders itself before all later work
    // and must not stand between the write and later writes.
    if (b.queue == kHostSlot) return;
    for (Record& r : seg.reads) {
        if (r.queue == b.queue && r.stage == b.stage) {
            r = b;  // a later read on the same queue and stage is ordered by whatever orders this one
            return;
        }
    }
    seg.reads.push_back(b);
}

bool SyncModel::State::resolves_elsewhere(AddressRange range) {
    return resolver && resolver->resolve(range, &resolved);
}

void SyncModel::State::record_resolved(const Record& b, const Access& access, bool deserialize) {
    if (!resolves_elsewhere(b.range)) {
        record(b, deserialize);
        return;
    }
    const std::vector<ResolvedRange> parts = resolved;
    for (const ResolvedRange& part : parts) {
        if (!part.bound) {
            if (on_unbound)
                on_unbound(commands[b.command], queue_of_slot(b.queue), access, part.range);
            continue;
        }
        Record piece = b;
        piece.range = part.range;
        record(piece, deserialize);
    }
}

DependencyInfo SyncModel::State::resolve_barriers(const DependencyInfo& dependency,
                                                  std::vector<BufferBarrier>& storage) {
    if (!resolver) return dependency;
    storage.clear();
    bool any = false;
    for (const BufferBarrier& b : dependency.buffer_barriers) {
        if (!resolves_elsewhere(b.range)) {
            storage.push_back(b);
            continue;
        }
        any = true;
        // An unbound part holds no memory, so the barrier orders no access there.
        for (const ResolvedRange& part : resolved)
            if (part.bound) storage.push_back({b.masks, part.range});
    }
    if (!any) return dependency;
    DependencyInfo out = dependency;
    out.buffer_barriers = storage;
    return out;
}

Record SyncModel::State::make_record(const Access& a, uint16_t queue, uint64_t t) {
    Record r;
    fill_record(r, a, queue, t);
    return r;
}

void SyncModel::State::fill_record(Record& r, const Access& a, uint16_t queue, uint64_t t) {
    fill_record(r, a, queue, t, intern(a.field));
}

void SyncModel::State::fill_record(Record& r, const Access& a, uint16_t queue, uint64_t t,
                                   uint32_t field) {
    r.element_bytes = 0;
    r.first_element = 0;
    r.field_suffix = 0;
    r.completed = false;
    r.sync.chain = 0;
    r.sync.avail = 0;
    r.sync.visible.clear();
    r.sync.signals.clear();
    r.tag = t;
    r.command = current_command;
    r.range = a.range;
    if (a.stage != last_masks.stage || a.access != last_masks.access)
        last_masks = {a.stage, a.access, atomic_stages(a.stage) & ~kEventStageBits,
                      atomic_accesses(a.access)};
    r.stage = last_masks.stage_atoms;
    r.access = a.access;
    r.atoms = last_masks.access_atoms;
    r.is_write = a.is_write;
    r.possible = a.possible;
    r.field = field;
    r.queue = queue;
    r.log_pos = queue == kHostSlot ? 0 : queues[queue].log_end();
}

void SyncModel::State::collect_commands() {
    kept_commands.clear();
    moved_to.assign(commands.size(), UINT32_MAX);
    auto keep = [&](uint32_t& command) {
        uint32_t& to = moved_to[command];
        if (to == UINT32_MAX) {
            to = uint32_t(kept_commands.size());
            kept_commands.push_back(commands[command]);
        }
        command = to;
    };
    keep(current_command);  // its next access may still come
    segments.for_each([&](Segment& seg, uint64_t, uint64_t) {
        if (seg.write) keep(seg.write->command);
        if (seg.possible_write) keep(seg.possible_write->command);
        for (Record& r : seg.reads) keep(r.command);
    });
    commands.swap(kept_commands);
    collect_at =
        commands.size() + std::max({kCollectFloor, commands.size(), std::size_t(segments.size())});
}

}  // namespace clastrace::replay
