// SPDX-License-Identifier: Apache-2.0
// SyncModel's public API (see sync_model.h); the model itself lives in the sync_*.cpp
// files that sync_model_internal.h lists.
#include "sync_model_internal.h"

#include <algorithm>
#include <iterator>

namespace clastrace::replay {

SyncModel::SyncModel(SyncOptions options) : state_(std::make_unique<State>()) {
    state_->options = options;
    state_->intern("");  // id 0: no field
}
SyncModel::~SyncModel() = default;

void SyncModel::set_address_resolver(AddressResolver* resolver, UnboundHandler on_unbound) {
    state_->resolver = resolver;
    state_->on_unbound = std::move(on_unbound);
}

void SyncModel::begin_submission(QueueId queue, uint32_t submission_index,
                                 std::span<const SemaphoreWait> waits) {
    State& s = *state_;
    s.current_queue = s.queue_slot(queue);
    s.current_submission = submission_index;
    s.in_submission = true;
    s.sync_tag();
    for (const SemaphoreWait& w : waits) {
        SemaphoreState& sem = s.semaphores[w.semaphore];
        std::optional<Clock> clock;
        NarrowSignal narrow;
        if (sem.binary_signal) {
            clock = std::move(sem.binary_signal);
            sem.binary_signal.reset();  // a binary wait consumes the signal
            narrow = sem.binary_narrow;
            sem.binary_narrow = {};
        } else if (auto it = sem.timeline.lower_bound(w.value); it != sem.timeline.end()) {
            clock = it->second;
            if (auto n = sem.timeline_narrow.find(it->first); n != sem.timeline_narrow.end())
                narrow = n->second;
        }
        if (!clock) {
            ++s.stats.unsatisfied_waits;
            continue;
        }
        clock->resize(s.queues.size(), 0);
        Queue& q = s.queues[s.current_queue];
        for (std::size_t i = 0; i < q.known.size(); ++i)
            q.known[i] = std::max(q.known[i], (*clock)[i]);
        Import im;
        im.log_pos = q.log_end();
        im.own = std::move(*clock);
        im.cumulative = q.known;
        // VUID-VkSubmitInfo-pWaitDstStageMask-00078: waits never name HOST; keep device stages.
        im.dst_scope = destination_scope_of(w.dst_stages) & kDeviceStages;
        im.signal = narrow.signal;
        im.signal_queue = narrow.queue;
        im.semaphore = w.semaphore;
        im.submission = submission_index;
        im.wait_stages = w.dst_stages;
        im.signal_stages = narrow.stages;
        im.signal_submission = narrow.submission;
        LogEntry e;
        e.kind = EntryKind::kImport;
        e.import_index = q.imports_base + uint32_t(q.imports.size());
        q.imports.push_back(std::move(im));
        q.log.push_back(e);
        ++s.stats.barriers;
    }
}

void SyncModel::record_access(const CommandRef& command, const Access& access) {
    State& s = *state_;
    s.maybe_collect_commands();
    const uint64_t t = s.command_tag(command, s.current_queue);
    s.record_resolved(s.make_record(access, s.current_queue, t), access, false);
}

void SyncModel::record_accesses(const CommandRef& command, std::span<const Access> accesses) {
    State& s = *state_;
    const std::size_t n = accesses.size();
    // Element runs need each access at its own addresses: one that resolves elsewhere (sparse
    // memory) takes the one-by-one path, which reports the same hazards.
    // One question for the command's hull first: memory that is its own address over the hull
    // is so over every part of it (most traces have no sparse memory at all).
    AddressRange hull{UINT64_MAX, 0};
    for (const Access& a : accesses) {
        if (a.range.empty()) continue;
        hull.begin = std::min(hull.begin, a.range.begin);
        hull.end = std::max(hull.end, a.range.end);
    }
    const bool resolving = s.resolves_elsewhere(hull) &&
                           std::any_of(accesses.begin(), accesses.end(), [&](const Access& a) {
                               return s.resolves_elsewhere(a.range);
                           });
    if (n < 2 || resolving) {
        for (const Access& a : accesses) record_access(command, a);
        return;
    }
    s.maybe_collect_commands();
    const uint64_t t = s.command_tag(command, s.current_queue);

    s.pin_overlapping(accesses);
    s.form_element_runs(accesses);
    auto& runs = s.batch.runs;
    auto& run_of = s.batch.run_of;
    auto& members = s.batch.members;
    auto& field_of = s.batch.field_of;

    // Findings are reported in the command's order (a run's at its elements' places), whatever
    // order the records go in.
    std::vector<State::Finding> found, each;
    std::vector<Record> laters;
    auto record_one = [&](uint32_t i) {
        const int32_t ri = run_of[i];
        const State::Run* run =
            ri >= 0 && runs[std::size_t(ri)].count > 1 ? &runs[std::size_t(ri)] : nullptr;
        CLASTRACE_DEBUG_ASSERT(!run || run->head == i);  // members go with their run's head
        Record& rec = s.batch.record;
        if (run) {
            Access a = accesses[i];
            a.range = run->range;
            s.fill_record(rec, a, s.current_queue, t, run->prefix);
            rec.element_bytes = uint32_t(run->bytes);
            rec.first_element = uint32_t(run->first);
            rec.field_suffix = run->suffix;
            s.stats.accesses += run->count - 1;  // counted per access, as record_access would
        } else {
            s.fill_record(rec, accesses[i], s.current_queue, t, field_of[i]);
        }
        each.clear();
        s.record(rec, false, &each);
        if (each.empty()) return;
        for (State::Finding& f : each) {
            f.order = i;
            if (f.later_element)
                f.order =
                    members[run->members_at + std::size_t((f.later_range.begin - rec.range.begin) /
                                                          rec.element_bytes)];
            f.later_record = uint32_t(laters.size());
        }
        laters.push_back(rec);
        found.insert(found.end(), std::make_move_iterator(each.begin()),
                     std::make_move_iterator(each.end()));
    };
    // Accesses overlapping another go in the command's order, which decides what they leave
    // behind. The others meet no other access of the command, so their order changes nothing
    // but the walk: in address order (pin_overlapping sorted them) they take one pass over the
    // segments.
    const auto& pinned = s.batch.pinned;
    for (uint32_t i = 0; i < n; ++i)
        if (pinned[i] || accesses[i].range.empty()) record_one(i);
    {
        struct SortedWalk {  // ended however record_one leaves
            SegmentStore<Segment>& store;
            explicit SortedWalk(SegmentStore<Segment>& s) : store(s) { store.begin_sorted(); }
            ~SortedWalk() { store.end_sorted(); }
        } walk(s.segments);
        for (const auto& [begin, i] : s.batch.by_begin) {
            if (pinned[i]) continue;
            const int32_t ri = run_of[i];
            if (ri >= 0 && runs[std::size_t(ri)].head != i) continue;  // goes with its run's head
            record_one(i);
        }
    }
    std::stable_sort(found.begin(), found.end(),
                     [](const State::Finding& a, const State::Finding& b) {
                         return a.order < b.order;
                     });
    for (const State::Finding& f : found) s.emit(f, laters[f.later_record]);
}

void SyncModel::record_copy(const CommandRef& command, const Access& source,
                            const Access& destination) {
    State& s = *state_;
    s.maybe_collect_commands();
    const uint64_t t = s.command_tag(command, s.current_queue);
    Record src = s.make_record(source, s.current_queue, t);
    Record dst = s.make_record(destination, s.current_queue, t);
    if (source.range.overlaps(destination.range)) {
        State::Finding f;
        f.key = {t, t, src.field, dst.field, HazardClass::kMoveOverlap};
        f.prior = src;
        f.fix = FixKind::kDisjointRanges;
        f.overlap = {std::max(source.range.begin, destination.range.begin),
                     std::min(source.range.end, destination.range.end)};
        s.emit(f, dst);
    }
    s.record_resolved(src, source, false);
    s.record_resolved(dst, destination, false);
}

void SyncModel::record_deserialize(const CommandRef& command, const Access& source,
                                   const Access& destination) {
    State& s = *state_;
    s.maybe_collect_commands();
    const uint64_t t = s.command_tag(command, s.current_queue);
    s.record_resolved(s.make_record(source, s.current_queue, t), source, false);
    s.record_resolved(s.make_record(destination, s.current_queue, t), destination, true);
}

void SyncModel::pipeline_barrier(const CommandRef& command, const DependencyInfo& dependency) {
    State& s = *state_;
    const uint64_t barrier_tag = s.sync_tag();
    std::vector<BufferBarrier> resolved;
    const uint32_t logged = s.queues[s.current_queue].log_end();
    s.log_barrier_entry(EntryKind::kBarrier, s.resolve_barriers(dependency, resolved), 0, false);
    if (s.queues[s.current_queue].log_end() != logged) s.remember_barrier(command, barrier_tag);
}

void SyncModel::set_event(const CommandRef& command, uint64_t event,
                          const DependencyInfo& dependency) {
    State& s = *state_;
    const uint64_t set_tag = s.sync_tag();
    EventState& ev = s.events[event];
    if (ev.slot < 0) {
        const int slot = s.next_slot;
        s.next_slot = (s.next_slot + 1) % kEventSlots;
        if (s.slot_used[std::size_t(slot)]) {
            ++s.stats.event_slot_reuses;
            s.events[s.slot_owner[std::size_t(slot)]].slot = -1;
        }
        s.slot_used[std::size_t(slot)] = true;
        s.slot_owner[std::size_t(slot)] = event;
        ev.slot = slot;
    }
    ev.set_serial = ++s.set_serial;
    ev.v1 = false;
    std::vector<BufferBarrier> resolved;
    s.log_barrier_entry(EntryKind::kEventSet, s.resolve_barriers(dependency, resolved),
                        StageMask(1) << (kFirstEventBit + ev.slot), false);
    s.remember_barrier(command, set_tag);
}

void SyncModel::set_event_v1(const CommandRef& command, uint64_t event,
                             VkPipelineStageFlags stages) {
    const MemoryBarrier b = memory_barrier_v1(stages, 0, 0, 0);
    set_event(command, event, DependencyInfo{std::span(&b, 1), {}, 0});
    Queue& q = state_->queues[state_->current_queue];
    q.log.back().v1_event = true;
    state_->events[event].v1 = true;
}

void SyncModel::reset_event(const CommandRef&, uint64_t event) {
    State& s = *state_;
    s.sync_tag();
    auto it = s.events.find(event);
    if (it == s.events.end() || it->second.slot < 0) return;
    s.slot_used[std::size_t(it->second.slot)] = false;
    it->second.slot = -1;
}

void SyncModel::wait_events(const CommandRef& command, std::span<const uint64_t> events,
                            const DependencyInfo& dependency) {
    State& s = *state_;
    const uint64_t wait_tag = s.sync_tag();
    StageMask bits = 0;
    bool v1 = false;
    for (uint64_t event : events) {
        auto it = s.events.find(event);
        if (it == s.events.end() || it->second.slot < 0)
            continue;  // never set on the device: orders nothing
        bits |= StageMask(1) << (kFirstEventBit + it->second.slot);
        v1 = v1 || it->second.v1;
    }
    if (!bits) return;
    std::vector<BufferBarrier> resolved;
    const uint32_t logged = s.queues[s.current_queue].log_end();
    s.log_barrier_entry(EntryKind::kEventWait, s.resolve_barriers(dependency, resolved), bits, v1);
    if (s.queues[s.current_queue].log_end() != logged) s.remember_barrier(command, wait_tag);
}

void SyncModel::end_submission(std::span<const SemaphoreSignal> signals, uint64_t fence) {
    State& s = *state_;
    s.sync_tag();
    const Clock clock = s.snapshot_now(s.current_queue);
    for (const SemaphoreSignal& sig : signals) {
        NarrowSignal narrow;
        const StageMask scope = source_scope_of(sig.src_stages) & kDeviceStages;
        if (scope != kDeviceStages) {
            // A mark in the log: catching a record up over it tells whether this signal's
            // first scope (its stages, or a chain into them) took the record in.
            narrow = {++s.next_signal, s.current_queue, sig.src_stages, s.current_submission};
            s.any_narrow = true;
            Queue& q = s.queues[s.current_queue];
            LogEntry e;
            e.kind = EntryKind::kSignal;
            e.event_bits = scope;
            e.signal = narrow.signal;
            e.first =
                q.pool_base + uint32_t(q.pool.size());  // no barriers: keeps the pool trim valid
            q.special_positions.push_back(q.log_end());
            q.log.push_back(e);
        }
        SemaphoreState& sem = s.semaphores[sig.semaphore];
        if (sig.value == 0) {
            sem.binary_signal = clock;
            sem.binary_narrow = narrow;
        } else {
            sem.timeline[sig.value] = clock;
            if (narrow.signal)
                sem.timeline_narrow[sig.value] = narrow;
            else
                sem.timeline_narrow.erase(sig.value);
        }
    }
    if (fence) s.fences[fence] = {clock, s.current_submission};
    s.in_submission = false;
    s.maybe_compact(s.queues[s.current_queue]);
}

void SyncModel::host_access(const CommandRef& command, const Access& access) {
    State& s = *state_;
    Access a = access;
    a.stage = VK_PIPELINE_STAGE_2_HOST_BIT;
    a.access = a.is_write ? VK_ACCESS_2_HOST_WRITE_BIT : VK_ACCESS_2_HOST_READ_BIT;
    s.maybe_collect_commands();
    const uint64_t t = s.command_tag(command, kHostSlot);
    s.record_resolved(s.make_record(a, kHostSlot, t), a, false);
}

void SyncModel::wait_for_fence(uint64_t fence) {
    State& s = *state_;
    s.sync_tag();
    auto it = s.fences.find(fence);
    if (it == s.fences.end()) return;
    if (it->second.submission) s.last_fence_wait.emplace(fence, *it->second.submission);
    s.complete_through(it->second.clock, false);
}

void SyncModel::queue_wait_idle(QueueId queue) {
    State& s = *state_;
    s.sync_tag();
    const uint16_t slot = s.queue_slot(queue);
    s.complete_through(s.snapshot_now(slot), true);
}

void SyncModel::device_wait_idle() {
    State& s = *state_;
    s.sync_tag();
    Clock all(s.queues.size(), s.tag + 1);
    s.complete_through(all, true);
}

void SyncModel::memory_freed(AddressRange range) {
    State& s = *state_;
    // Completed accesses to freed memory can order nothing any more; the host kept
    // completed writes only for its own later reads, which freed memory cannot have.
    // Accesses still in flight stay: memory freed and reused under them is a hazard.
    s.segments.erase_if(
        [&](Segment& seg, uint64_t seg_begin, uint64_t seg_end) {
            if (seg_begin < range.begin || seg_end > range.end) return false;
            std::erase_if(seg.reads, [&](const Record& r) {
                return r.queue == kHostSlot || r.tag < s.queues[r.queue].complete;
            });
            auto drop_completed = [&](auto& w) {  // the certain or the possible write
                if (w &&
                    (w->queue == kHostSlot || w->completed || w->tag < s.queues[w->queue].complete))
                    w.reset();
            };
            drop_completed(seg.write);
            drop_completed(seg.possible_write);
            return seg.empty();
        },
        range.begin, range.end);
    s.stats.segments = s.segments.size();
}

void SyncModel::host_wait_semaphore(uint64_t semaphore, uint64_t value) {
    State& s = *state_;
    s.sync_tag();
    auto sem = s.semaphores.find(semaphore);
    if (sem == s.semaphores.end()) return;
    auto it = sem->second.timeline.lower_bound(value);
    if (it == sem->second.timeline.end()) return;
    s.complete_through(it->second, false);
}

void SyncModel::host_signal_semaphore(uint64_t semaphore, uint64_t value) {
    State& s = *state_;
    s.sync_tag();
    s.semaphores[semaphore].timeline[value] = Clock(s.queues.size(), 0);
}

void SyncModel::present_wait(std::span<const uint64_t> semaphores) {
    State& s = *state_;
    for (uint64_t semaphore : semaphores) {
        auto sem = s.semaphores.find(semaphore);
        if (sem == s.semaphores.end())
            continue;  // signalled outside the trace (another frame range)
        sem->second.binary_signal.reset();
        sem->second.binary_narrow = {};
    }
}

void SyncModel::acquire_signal(uint64_t semaphore, uint64_t fence) {
    State& s = *state_;
    s.sync_tag();
    if (semaphore) {
        SemaphoreState& sem = s.semaphores[semaphore];
        sem.binary_signal = Clock(s.queues.size(), 0);
        sem.binary_narrow = {};
    }
    if (fence) s.fences[fence] = {Clock(s.queues.size(), 0), std::nullopt};
}

const std::vector<HazardReport>& SyncModel::hazards() const { return state_->reports; }
const SyncStats& SyncModel::stats() const { return state_->stats; }

std::size_t SyncModel::memory_bytes() const {
    const State& s = *state_;
    std::size_t bytes = s.segments.memory_bytes([](const Segment& seg) {
        return seg.reads.capacity() * sizeof(Record) + (seg.possible_write ? sizeof(Record) : 0);
    });
    bytes += (s.commands.capacity() + s.kept_commands.capacity()) * sizeof(CommandRef) +
             s.moved_to.capacity() * sizeof(uint32_t);
    for (const Queue& q : s.queues) {
        bytes += q.log.capacity() * sizeof(LogEntry) + q.pool.capacity() * sizeof(LoggedBarrier);
        for (const Import& im : q.imports)
            bytes += sizeof(Import) + (im.own.size() + im.cumulative.size()) * 8;
    }
    return bytes;
}

}  // namespace clastrace::replay
