// SPDX-License-Identifier: Apache-2.0
// SyncModel's lazy barrier log: a record's chain state catches up over its queue's log
// only when a later access asks about it (and through semaphore waits, from other queues).
#include "sync_model_internal.h"

#include <algorithm>

namespace clastrace::replay {

namespace {

// An access is in a first synchronization scope when every stage it runs in is: a draw whose
// mesh and fragment shaders may both write (replay's CmdDraw) is not ordered by a barrier from
// the fragment stage alone. Every other access runs in one stage, where this is `scope & stage`.
bool in_first_scope(StageMask scope, StageMask stage) {
    return stage != 0 && (scope & stage) == stage;
}

}  // namespace

void SyncModel::State::apply_barriers(const Queue& q, const LogEntry& e, ChainState& s,
                                      const Record& r, bool home, uint64_t seg_begin,
                                      uint64_t seg_end) {
    // All barriers of one command act at once: decide each against the state before any.
    StageMask add_chain = 0, add_avail = 0;
    uint64_t makes_visible = 0;  // bit i: barrier i makes the write visible
    const AccessMask write_atoms = r.atoms & kWriteAtoms;
    const uint32_t count = std::min<uint32_t>(e.count, 64);
    for (uint32_t i = 0; i < count; ++i) {
        const LoggedBarrier& b = q.pool[e.first + i - q.pool_base];
        if (!b.global && !contains(b.range, seg_begin, seg_end)) continue;
        const bool direct = home && in_first_scope(b.src_scope, r.stage);
        if (!direct && !(s.chain & b.src_scope)) continue;
        add_chain |= b.dst_scope;
        if (!r.is_write) continue;
        const bool in_access_scope = direct && (write_atoms & b.src_atoms) == write_atoms;
        if (in_access_scope || (s.avail & b.src_scope)) {
            add_avail |= b.dst_scope;
            makes_visible |= uint64_t(1) << i;
        }
    }
    s.chain |= add_chain;
    s.avail |= add_avail;
    for (uint64_t m = makes_visible; m; m &= m - 1) {
        const LoggedBarrier& b = q.pool[e.first + uint32_t(__builtin_ctzll(m)) - q.pool_base];
        stats.visibility_spills += s.visible.add(b.dst_scope, b.dst_atoms);
    }
}

void SyncModel::State::apply_event_set(const Queue& q, const LogEntry& e, ChainState& s,
                                       const Record& r, bool home, uint64_t seg_begin,
                                       uint64_t seg_end) {
    // The slot may carry an older set of a reused event: this set starts it afresh.
    s.chain &= ~e.event_bits;
    s.avail &= ~e.event_bits;
    const AccessMask write_atoms = r.atoms & all_write_accesses();
    for (uint32_t i = 0; i < e.count; ++i) {
        const LoggedBarrier& b = q.pool[e.first + i - q.pool_base];
        if (!b.global && !contains(b.range, seg_begin, seg_end)) continue;
        const bool direct = home && in_first_scope(b.src_scope, r.stage);
        if (!direct && !(s.chain & b.src_scope & ~kEventStageBits)) continue;
        s.chain |= e.event_bits;
        if (!r.is_write) continue;
        const bool in_access_scope =
            direct && (e.v1_event || (write_atoms & b.src_atoms) == write_atoms);
        if (in_access_scope || (s.avail & b.src_scope & ~kEventStageBits)) s.avail |= e.event_bits;
    }
}

void SyncModel::State::apply_event_wait(const Queue& q, const LogEntry& e, ChainState& s,
                                        const Record& r, uint64_t seg_begin, uint64_t seg_end) {
    if (!(s.chain & e.event_bits)) return;
    StageMask add_chain = 0, add_avail = 0;
    Visibility add_visible;
    const AccessMask write_atoms = r.atoms & all_write_accesses();
    for (uint32_t i = 0; i < e.count; ++i) {
        const LoggedBarrier& b = q.pool[e.first + i - q.pool_base];
        if (!b.global && !contains(b.range, seg_begin, seg_end)) continue;
        add_chain |= b.dst_scope;
        if (!r.is_write || !(s.avail & e.event_bits)) continue;
        // A v1 set names no accesses; the wait's source access mask stands in for it.
        if (e.v1_event && (write_atoms & b.src_atoms) != write_atoms) continue;
        add_avail |= b.dst_scope;
        add_visible.add(b.dst_scope, b.dst_atoms);
    }
    s.chain |= add_chain;
    s.avail |= add_avail;
    for (std::size_t i = 0; i < add_visible.size(); ++i)
        stats.visibility_spills +=
            s.visible.add(add_visible.at(i).stages, add_visible.at(i).accesses);
}

void SyncModel::State::apply_entry(const Queue& q, uint32_t pos, ChainState& s, const Record& r,
                                   bool home, uint64_t seg_begin, uint64_t seg_end) {
    const LogEntry& e = q.log[pos - q.log_base];
    ++stats.log_entries_applied;
    switch (e.kind) {
    case EntryKind::kBarrier: apply_barriers(q, e, s, r, home, seg_begin, seg_end); break;
    case EntryKind::kEventSet: apply_event_set(q, e, s, r, home, seg_begin, seg_end); break;
    case EntryKind::kEventWait: apply_event_wait(q, e, s, r, seg_begin, seg_end); break;
    case EntryKind::kSignal: {
        const bool direct = home && in_first_scope(e.event_bits, r.stage);
        if (direct || (s.chain & e.event_bits))
            s.signals.push_back({e.signal, !r.is_write || direct || (s.avail & e.event_bits) != 0});
        break;
    }
    case EntryKind::kImport: {
        const Import& im = q.imports[e.import_index - q.imports_base];
        bool available = true;
        if (covered(im.own, r.queue) > r.tag &&
            (!im.signal || in_signal(im, r, seg_begin, seg_end, &available))) {
            s.chain |= im.dst_scope;
            if (r.is_write && available) {
                s.avail |= im.dst_scope;
                s.visible.add(im.dst_scope, all_read_accesses() | all_write_accesses());
            }
        }
        break;
    }
    }
}

bool SyncModel::State::settled(const Record& r) {
    const StageMask device = all_device_stages();
    if ((r.sync.chain & device) != device) return false;
    if (!r.is_write) return true;
    if ((r.sync.avail & device) != device) return false;
    const AccessMask all = all_read_accesses() | all_write_accesses();
    for (std::size_t i = 0; i < r.sync.visible.size(); ++i) {
        const Visibility::Rect& rect = r.sync.visible.at(i);
        if ((rect.stages & device) == device && (rect.accesses & all) == all) return true;
    }
    return false;
}

void SyncModel::State::apply_full(Record& r) {
    const StageMask device = all_device_stages();
    r.sync.chain |= device;
    if (!r.is_write) return;
    r.sync.avail |= device;
    r.sync.visible.add(device, all_read_accesses() | all_write_accesses());
}

void SyncModel::State::catch_up(Record& r, uint64_t seg_begin, uint64_t seg_end) {
    if (r.queue == kHostSlot || r.completed) return;
    const Queue& q = queues[r.queue];
    const uint32_t end = q.log_end();
    uint32_t pos = r.log_pos;
    while (pos < end) {
        auto sp = std::lower_bound(q.special_positions.begin(), q.special_positions.end(), pos);
        const uint32_t next_special = sp == q.special_positions.end() ? end : *sp;
        if (!settled(r)) {
            auto f =
                std::lower_bound(q.full_positions.begin(), q.full_positions.end(), next_special);
            if (f != q.full_positions.begin() && *(f - 1) >= pos) {
                apply_full(r);
                ++stats.log_entries_applied;
                pos = *(f - 1) + 1;
            }
            while (pos < next_special && !settled(r)) {
                const LogEntry& e = q.log[pos - q.log_base];
                apply_entry(q, pos, r.sync, r, true, seg_begin, seg_end);
                uint32_t next = pos + 1;
                if (e.run_start != kNoRun && e.run_start >= q.log_base)
                    next = std::max(next, std::min(q.log[e.run_start - q.log_base].run_end,
                                                   next_special));
                pos = next;
            }
        }
        pos = next_special;
        if (pos < end) apply_entry(q, pos++, r.sync, r, true, seg_begin, seg_end);
    }
    r.log_pos = end;
}

std::optional<ChainState> SyncModel::State::foreign_view(const Record& r, const Queue& w,
                                                         uint64_t seg_begin, uint64_t seg_end) {
    auto it = std::partition_point(w.imports.begin(), w.imports.end(), [&](const Import& im) {
        return covered(im.cumulative, r.queue) <= r.tag;
    });
    if (it == w.imports.end()) return std::nullopt;
    ChainState s;
    for (uint32_t pos = it->log_pos; pos < w.log_end(); ++pos)
        apply_entry(w, pos, s, r, false, seg_begin, seg_end);
    return s;
}

bool SyncModel::State::in_signal(const Import& im, const Record& r, uint64_t seg_begin,
                                 uint64_t seg_end, bool* available) {
    const RareList<SignalMembership>* list =
        &r.sync.signals;  // r's own queue signaled: caught up past it
    std::optional<ChainState> view;
    if (im.signal_queue != r.queue) {
        // A record of a third queue: what the signaling queue's log did with it.
        if (foreign_depth >= 4) return true;  // long chains of narrow signals: assume taken in
        ++foreign_depth;
        view = foreign_view(r, queues[im.signal_queue], seg_begin, seg_end);
        --foreign_depth;
        if (!view) return false;
        list = &view->signals;
    }
    for (const SignalMembership& m : *list) {
        if (m.signal == im.signal) {
            *available = m.available;
            return true;
        }
    }
    return false;
}

}  // namespace clastrace::replay
