// SPDX-License-Identifier: Apache-2.0
// SyncModel's barriers: pipeline barriers and event operations pooled and logged per queue.
#include "sync_model_internal.h"

namespace clastrace::replay {

uint32_t SyncModel::State::pool_barriers(Queue& q, const DependencyInfo& dep) {
    const uint32_t first = q.pool_base + uint32_t(q.pool.size());
    for (const MemoryBarrier& m : dep.memory_barriers) {
        q.pool.push_back({source_scope_of(m.src_stages),
                          destination_scope_of(m.dst_stages),
                          atomic_accesses(m.src_access),
                          atomic_accesses(m.dst_access),
                          {},
                          true});
    }
    for (const BufferBarrier& bb : dep.buffer_barriers) {
        if (bb.range.empty()) continue;
        q.pool.push_back({source_scope_of(bb.masks.src_stages),
                          destination_scope_of(bb.masks.dst_stages),
                          atomic_accesses(bb.masks.src_access),
                          atomic_accesses(bb.masks.dst_access), bb.range, false});
        // Segments must lie wholly inside or outside every buffer barrier's range.
        split_at(bb.range.begin);
        split_at(bb.range.end);
    }
    stats.barriers += dep.memory_barriers.size() + dep.buffer_barriers.size();
    return first;
}

void SyncModel::State::log_barrier_entry(EntryKind kind, const DependencyInfo& dep,
                                         StageMask event_bits, bool v1) {
    Queue& q = queues[current_queue];
    LogEntry e;
    e.kind = kind;
    e.first = pool_barriers(q, dep);
    e.count = q.pool_base + uint32_t(q.pool.size()) - e.first;
    e.event_bits = event_bits;
    e.v1_event = v1;
    if (e.count == 0 && kind == EntryKind::kBarrier) return;
    const StageMask device = all_device_stages();
    const AccessMask all = all_read_accesses() | all_write_accesses();
    bool special = kind == EntryKind::kEventSet, full = false;
    for (uint32_t i = 0; i < e.count; ++i) {
        const LoggedBarrier& b = q.pool[e.first + i - q.pool_base];
        special = special || (b.dst_scope & ~device);
        full = full || (kind == EntryKind::kBarrier && b.global &&
                        (b.src_scope & device) == device && (b.dst_scope & device) == device &&
                        (b.src_atoms & all_write_accesses()) == all_write_accesses() &&
                        (b.dst_atoms & all) == all);
    }
    const uint32_t pos = q.log_end();
    e.run_start = pos;
    e.run_end = pos + 1;
    if (special) {
        q.special_positions.push_back(pos);
    } else if (full) {
        q.full_positions.push_back(pos);
    } else if (kind == EntryKind::kBarrier && e.count == 1 && !q.log.empty()) {
        const LogEntry& prev = q.log.back();
        if (prev.kind == EntryKind::kBarrier && prev.count == 1 && prev.run_end == pos &&
            same_barrier(q.pool[prev.first - q.pool_base], q.pool[e.first - q.pool_base])) {
            q.pool.pop_back();  // share the run's pooled barrier
            e.first = prev.first;
            e.run_start = prev.run_start;
            q.log[prev.run_start - q.log_base].run_end = pos + 1;
        }
    }
    if (e.run_start == pos && !(kind == EntryKind::kBarrier && e.count == 1 && !special && !full))
        e.run_start = kNoRun;  // not a run member: catch-up never skips past it
    q.log.push_back(e);
    maybe_compact(q);
}

}  // namespace clastrace::replay
