// SPDX-License-Identifier: Apache-2.0
// SyncModel's host waits: work the host saw complete is retired, and logs no record needs
// are trimmed.
#include "sync_model_internal.h"

#include <algorithm>
#include <iterator>

namespace clastrace::replay {

void SyncModel::State::complete_through(const Clock& clock, bool always_sweep) {
    for (std::size_t i = 0; i < queues.size() && i < clock.size(); ++i)
        queues[i].complete = std::max(queues[i].complete, clock[i]);
    if (!always_sweep && segments.size() < sweep_at) return;
    retire();
    prune_timelines();
    sweep_at = std::max(kSweepFloor, 2 * segments.size());
}

bool SyncModel::State::all_complete(const Clock& c) const {
    for (std::size_t i = 0; i < c.size() && i < queues.size(); ++i)
        if (c[i] > queues[i].complete) return false;
    return true;
}

void SyncModel::State::prune_timelines() {
    for (auto& [handle, sem] : semaphores) {
        auto& timeline = sem.timeline;
        for (auto it = timeline.begin(); it != timeline.end();) {
            auto next = std::next(it);
            if (next != timeline.end() && all_complete(it->second) && all_complete(next->second))
                it = timeline.erase(it);
            else
                it = next;
        }
    }
}

void SyncModel::State::retire() {
    segments.erase_if([&](Segment& seg, uint64_t seg_begin, uint64_t seg_end) {
        std::erase_if(seg.reads, [&](const Record& r) {
            return r.queue == kHostSlot || r.tag < queues[r.queue].complete;
        });
        auto retire_write = [&](auto& slot) {  // the certain or the possible write
            if (!slot) return;
            Record& w = *slot;
            if (w.queue == kHostSlot) {
                slot.reset();
            } else if (!w.completed && w.tag < queues[w.queue].complete) {
                catch_up(w, seg_begin, seg_end);
                if (w.sync.visible.covers(VK_PIPELINE_STAGE_2_HOST_BIT, VK_ACCESS_2_HOST_READ_BIT))
                    slot.reset();
                else
                    w.completed = true;
            }
        };
        retire_write(seg.write);
        retire_write(seg.possible_write);
        return seg.empty();
    });
    trim_logs();
    for (Queue& q : queues) q.log_size_after_trim = q.log.size();
    stats.segments = segments.size();
}

void SyncModel::State::trim_logs() {
    std::vector<uint32_t> keep(queues.size());
    for (std::size_t i = 0; i < queues.size(); ++i) keep[i] = queues[i].log_end();
    auto need = [&](const Record& r) {
        if (r.queue == kHostSlot || r.completed) return;
        keep[r.queue] = std::min(keep[r.queue], r.log_pos);
        for (std::size_t w = 0; w < queues.size(); ++w) {
            if (w == r.queue) continue;
            const auto& ims = queues[w].imports;
            auto it = std::partition_point(ims.begin(), ims.end(), [&](const Import& im) {
                return covered(im.cumulative, r.queue) <= r.tag;
            });
            if (it != ims.end()) keep[w] = std::min(keep[w], it->log_pos);
        }
    };
    segments.for_each([&](const Segment& seg, uint64_t, uint64_t) {
        if (seg.write) need(*seg.write);
        if (seg.possible_write) need(*seg.possible_write);
        for (const Record& r : seg.reads) need(r);
    });
    for (std::size_t i = 0; i < queues.size(); ++i) {
        Queue& q = queues[i];
        const uint32_t drop = keep[i] - q.log_base;
        if (drop == 0) continue;
        // Barriers and imports referenced by the kept entries stay.
        uint32_t pool_keep = q.pool_base + uint32_t(q.pool.size());
        uint32_t import_keep = q.imports_base + uint32_t(q.imports.size());
        for (uint32_t k = drop; k < q.log.size(); ++k) {
            const LogEntry& e = q.log[k];
            if (e.kind == EntryKind::kImport)
                import_keep = std::min(import_keep, e.import_index);
            else
                pool_keep = std::min(pool_keep, e.first);
        }
        if (drop < q.log.size()) {
            // A run cut by the trim gets its first kept entry as new head.
            const uint32_t head = q.log[drop].run_start;
            if (head != kNoRun && head < keep[i]) {
                const uint32_t end = q.log[head - q.log_base].run_end;
                for (std::size_t k = drop; k < q.log.size() && q.log[k].run_start == head; ++k)
                    q.log[k].run_start = keep[i];
                q.log[drop].run_end = end;
            }
        }
        q.log.erase(q.log.begin(), q.log.begin() + drop);
        q.log_base += drop;
        std::erase_if(q.full_positions, [&](uint32_t p) { return p < q.log_base; });
        std::erase_if(q.special_positions, [&](uint32_t p) { return p < q.log_base; });
        q.pool.erase(q.pool.begin(), q.pool.begin() + (pool_keep - q.pool_base));
        q.pool_base = pool_keep;
        // Imports also serve the binary search; only those wholly before the kept log go.
        uint32_t import_drop = 0;
        while (import_drop < q.imports.size() && q.imports_base + import_drop < import_keep &&
               q.imports[import_drop].log_pos < q.log_base)
            ++import_drop;
        q.imports.erase(q.imports.begin(), q.imports.begin() + import_drop);
        q.imports_base += import_drop;
    }
}

void SyncModel::State::maybe_compact(const Queue& q) {
    if (q.log.size() > 4096 && q.log.size() > 2 * q.log_size_after_trim) compact();
}

void SyncModel::State::compact() {
    segments.for_each([&](Segment& seg, uint64_t begin, uint64_t end) {
        if (seg.write) catch_up(*seg.write, begin, end);
        if (seg.possible_write) catch_up(*seg.possible_write, begin, end);
        for (Record& r : seg.reads) catch_up(r, begin, end);
    });
    trim_logs();
    for (Queue& q : queues) q.log_size_after_trim = q.log.size();
}

Clock SyncModel::State::snapshot_now(uint16_t slot) {
    Clock c = queues[slot].known;
    c[slot] = tag + 1;
    return c;
}

}  // namespace clastrace::replay
