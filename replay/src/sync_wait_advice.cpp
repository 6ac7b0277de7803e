// SPDX-License-Identifier: Apache-2.0
// The advice on a hazard the application meant to order with a wait or a barrier that missed
// it (SyncModel::State::wait_advice, barrier_advice): the fix names what orders the two
// accesses; this names the wait or barrier that was there, so the author finds the line to
// change.
#include "clastrace/common/hex.h"
#include "clastrace/replay/sync_masks.h"
#include "hazard_text.h"
#include "sync_model_internal.h"

#include <string>

namespace clastrace::replay {

namespace {

std::string submission_text(uint32_t submission) {
    return "submission " + std::to_string(submission);
}

// What a barrier logged as `e` leaves out of ordering `prior` before `later` over `overlap`;
// empty when nothing (the hazard then comes from elsewhere). An event splits the barrier: its
// set holds the source half (stages, and the access mask but for a synchronization-1 set,
// which names none), its wait the destination half (and, in synchronization 1, the source
// access mask); a synchronization-2 wait repeats the set's dependency, so its source half is
// the set's to name. Reads of several types need one of them visible (docs/replay.md,
// "Programs written apart").
std::string what_barrier_misses(const LogEntry& e, const LoggedBarrier& b, const Record& prior,
                                const Record& later, AddressRange overlap) {
    const bool source_only = e.kind == EntryKind::kEventSet;
    const bool destination_only = e.kind == EntryKind::kEventWait;
    if (!b.global && !contains(b.range, overlap.begin, overlap.end))
        return "its buffer range " + range_text(b.range) + " leaves these bytes out";
    if (!destination_only && (b.src_scope & prior.stage) != prior.stage)
        return "its srcStageMask leaves out " + stage_names(prior.stage);
    if (!source_only && (b.dst_scope & later.stage) != later.stage)
        return "its dstStageMask leaves out " + stage_names(later.stage);
    if (!prior.is_write || (source_only && e.v1_event)) return {};
    const AccessMask written = prior.atoms & kWriteAtoms;
    const bool names_source_access = !destination_only || e.v1_event;
    if (names_source_access && (b.src_atoms & written) != written)
        return "its srcAccessMask leaves out " + access_names(written) +
               ": it orders execution but does not make the write available";
    if (source_only) return {};
    const AccessMask seen = later.atoms & b.dst_atoms;
    if (later.is_write ? seen != later.atoms : seen == 0)
        return "its dstAccessMask leaves out " + access_names(later.access) +
               ": the write is not made visible to that access";
    return {};
}

// Whether the narrow signal `im` waits on took `prior` in (its stages, or a chain into them):
// what catching `prior` up over the signal's mark noted; a record of another queue than the
// signal's is taken as in (the hazard then comes from elsewhere).
bool signal_took_in(const Import& im, const Record& prior) {
    if (im.signal_queue != prior.queue) return true;
    for (const SignalMembership& m : prior.sync.signals)
        if (m.signal == im.signal) return true;
    return false;
}

// How far a barrier's buffer range lies from `bytes` (0: global, touching or overlapping).
uint64_t distance_to(const LoggedBarrier& b, AddressRange bytes) {
    if (b.global || (b.range.begin <= bytes.end && bytes.begin <= b.range.end)) return 0;
    return b.range.end < bytes.begin ? bytes.begin - b.range.end : b.range.begin - bytes.end;
}

const char* barrier_kind_text(EntryKind kind) {
    switch (kind) {
    case EntryKind::kEventSet: return "The event set";
    case EntryKind::kEventWait: return "The event wait";
    default: return "The barrier";
    }
}

}  // namespace

std::string SyncModel::State::wait_advice(const Record& prior, const Record& later,
                                          const HazardReport& report) const {
    if (prior.queue == kHostSlot) return {};
    if (later.queue == kHostSlot) {
        // A host write racing a submission the host did wait for a fence of, but an earlier one.
        if (!later.is_write || !last_fence_wait) return {};
        const auto& [fence, waited] = *last_fence_wait;
        if (waited >= report.prior.command.submission) return {};
        return "The host last waited on fence " + common::hex(fence) + ", signaled by " +
               submission_text(waited) + ", which does not include " +
               submission_text(report.prior.command.submission) +
               ": wait on the fence of that submission (or of a later one on its queue).";
    }
    // A semaphore wait whose signal came after the prior access (so it would order it) but
    // whose stage mask leaves out the later access's stage; or whose signal's stage mask
    // left the prior access out (its first synchronization scope).
    const Queue& q = queues[later.queue];
    for (const Import& im : q.imports) {
        if (covered(im.own, prior.queue) <= prior.tag) continue;
        if (im.signal && !signal_took_in(im, prior))
            return "The signal of semaphore " + common::hex(im.semaphore) + " by " +
                   submission_text(im.signal_submission) + ", which " +
                   submission_text(im.submission) + " waits on, is at " +
                   stage_names(im.signal_stages) + " only: add " + stage_names(prior.stage) +
                   " to the signal's stage mask (VkSemaphoreSubmitInfo::stageMask).";
        if (im.dst_scope & later.stage) continue;
        return "The wait of " + submission_text(im.submission) + " on semaphore " +
               common::hex(im.semaphore) + " follows " +
               submission_text(report.prior.command.submission) + "'s access, but at " +
               stage_names(im.wait_stages) + " only: add " + stage_names(later.stage) +
               " to the wait's stage mask (pWaitDstStageMask, VkSemaphoreSubmitInfo::stageMask).";
    }
    return {};
}

void SyncModel::State::remember_barrier(const CommandRef& command, uint64_t barrier_tag) {
    const Queue& q = queues[current_queue];
    BarrierCommand b{barrier_tag, current_queue, q.log_end() - 1, command};
    if (recent_barriers.size() < kRecentBarriers) {
        recent_barriers.push_back(b);
        return;
    }
    recent_barriers[next_recent_barrier] = b;
    next_recent_barrier = (next_recent_barrier + 1) % kRecentBarriers;
}

std::string SyncModel::State::barrier_advice(const Record& prior, const Record& later,
                                             const HazardReport& report) const {
    if (prior.queue == kHostSlot || prior.queue != later.queue) return {};
    const Queue& q = queues[later.queue];
    const BarrierCommand* nearest = nullptr;  // the last barrier between the two
    std::string missed;
    for (const BarrierCommand& b : recent_barriers) {
        if (b.queue != later.queue || b.tag <= prior.tag || b.tag >= later.tag) continue;
        if (nearest && nearest->tag > b.tag) continue;
        if (b.log_pos < q.log_base || b.log_pos >= q.log_end()) continue;
        const LogEntry& e = q.log[b.log_pos - q.log_base];
        if (e.first < q.pool_base) continue;
        // One barrier of the command that misses nothing: the hazard came from elsewhere. (A
        // reset between an event's set and its wait is left to the fix's text.) Of several,
        // the one whose range lies nearest the bytes says why: it was meant for them.
        std::string why;
        uint64_t why_distance = UINT64_MAX;
        bool all_miss = e.count > 0;
        for (uint32_t i = 0; i < e.count && all_miss; ++i) {
            const LoggedBarrier& lb = q.pool[e.first + i - q.pool_base];
            std::string reason = what_barrier_misses(e, lb, prior, later, report.overlap);
            all_miss = !reason.empty();
            const uint64_t distance = distance_to(lb, report.overlap);
            if (distance < why_distance) {
                why = std::move(reason);
                why_distance = distance;
            }
        }
        if (!all_miss) continue;
        nearest = &b;
        missed = std::move(why);
    }
    if (!nearest) return {};
    const EntryKind kind = q.log[nearest->log_pos - q.log_base].kind;
    return std::string(barrier_kind_text(kind)) + " between them, " +
           command_place_text(nearest->command, report.later.queue) + ", misses: " + missed + ".";
}

}  // namespace clastrace::replay
