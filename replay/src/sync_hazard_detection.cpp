// SPDX-License-Identifier: Apache-2.0
// SyncModel's hazard decisions: is an earlier access ordered before (and visible to) a later
// one, and the findings and reports when it is not.
#include "sync_model_internal.h"

#include <algorithm>
#include <bit>
#include <string>

namespace clastrace::replay {

namespace {

// A read that carries several access types (the spec leaves open which one the command uses: a
// cluster build's pointed-to inputs) is visible once one of them is; a write, and a read of one
// type, need every atomic access of theirs.
bool visible_to(const Visibility& visible, StageMask stage, const Record& later) {
    if (later.is_write || std::popcount(later.access) < 2)
        return visible.covers(stage, later.atoms);
    for (AccessMask m = later.access; m; m &= m - 1)
        if (visible.covers(stage, atomic_accesses(m & (~m + 1)))) return true;
    return false;
}

}  // namespace

std::optional<FixKind> SyncModel::State::unordered(Record& prior, const Later& later,
                                                   bool need_visible, uint64_t seg_begin,
                                                   uint64_t seg_end) {
    const Record& b = *later.record;
    if (prior.queue == kHostSlot)
        return std::nullopt;  // host work before the submit: ordered and visible
    const bool prior_complete = prior.completed || prior.tag < queues[prior.queue].complete;
    if (later.queue == kHostSlot) {
        if (!prior_complete)
            return need_visible ? FixKind::kHostWaitAndBarrier : FixKind::kHostWait;
        if (!need_visible || b.is_write) return std::nullopt;
        catch_up(prior, seg_begin, seg_end);
        return prior.sync.visible.covers(VK_PIPELINE_STAGE_2_HOST_BIT, b.atoms)
                   ? std::nullopt
                   : std::optional<FixKind>(FixKind::kHostWaitAndBarrier);
    }
    if (prior_complete) return std::nullopt;
    const ChainState* s = nullptr;
    std::optional<ChainState> foreign;
    if (prior.queue == later.queue) {
        catch_up(prior, seg_begin, seg_end);
        s = &prior.sync;
    } else {
        if (any_narrow) catch_up(prior, seg_begin, seg_end);  // its narrow-signal memberships
        foreign = foreign_view(prior, queues[later.queue], seg_begin, seg_end);
        if (!foreign) return FixKind::kSemaphore;
        s = &*foreign;
    }
    const bool ok = need_visible ? visible_to(s->visible, b.stage, b) : (s->chain & b.stage) != 0;
    if (ok) return std::nullopt;
    return prior.queue == later.queue ? FixKind::kPipelineBarrier : FixKind::kSemaphore;
}

void SyncModel::State::element_of(const Record& r, uint64_t at, uint32_t* field,
                                  AddressRange* range) {
    if (!r.element_bytes) {
        *field = r.field;
        *range = r.range;
        return;
    }
    const uint64_t k = (at - r.range.begin) / r.element_bytes;
    range->begin = r.range.begin + k * r.element_bytes;
    range->end = range->begin + r.element_bytes;
    const std::string name =
        field_names[r.field] + std::to_string(r.first_element + k) + field_names[r.field_suffix];
    *field = intern(name);
}

void SyncModel::State::note_one(std::vector<Finding>& found, HazardKey key, const Record& prior,
                                const AddressRange& prior_range, const Record& later,
                                const AddressRange& later_range, FixKind fix, uint64_t begin,
                                uint64_t end) {
    Finding* same = nullptr;
    if (found.size() <= 16) {
        for (Finding& f : found)
            if (f.key == key) same = &f;
    } else {
        if (found_index.empty())
            for (std::size_t i = 0; i < found.size(); ++i) found_index.emplace(found[i].key, i);
        if (auto it = found_index.find(key); it != found_index.end()) same = &found[it->second];
    }
    if (same) {  // the same two accesses over adjacent segments: widen the region
        same->overlap.begin = std::min(same->overlap.begin, begin);
        same->overlap.end = std::max(same->overlap.end, end);
        return;
    }
    Finding f;
    f.key = key;
    f.prior = prior;
    f.fix = fix;
    f.overlap = {begin, end};
    if (prior.element_bytes) {
        f.prior.range = prior_range;
        f.prior.field = key.prior_field;
        f.prior.element_bytes = 0;
    }
    if (later.element_bytes) {
        f.later_element = true;
        f.later_field = key.later_field;
        f.later_range = later_range;
    }
    if (!found_index.empty()) found_index.emplace(key, found.size());
    found.push_back(std::move(f));
}

void SyncModel::State::note(std::vector<Finding>& found, HazardClass hazard, const Record& prior,
                            const Record& later, FixKind fix, uint64_t seg_begin,
                            uint64_t seg_end) {
    if (!prior.element_bytes && !later.element_bytes) {
        note_one(found, {prior.tag, later.tag, prior.field, later.field, hazard}, prior,
                 prior.range, later, later.range, fix, seg_begin, seg_end);
        return;
    }
    // Per pair of elements whose bytes meet, in address order: what record_access on
    // each element would have found segment by segment.
    for (uint64_t p = seg_begin; p < seg_end;) {
        uint32_t prior_field;
        AddressRange prior_range;
        element_of(prior, p, &prior_field, &prior_range);
        const uint64_t p_end = std::min(seg_end, prior_range.end);
        for (uint64_t l = p; l < p_end;) {
            uint32_t later_field;
            AddressRange later_range;
            element_of(later, l, &later_field, &later_range);
            const uint64_t l_end = std::min(p_end, later_range.end);
            note_one(found, {prior.tag, later.tag, prior_field, later_field, hazard}, prior,
                     prior_range, later, later_range, fix, l, l_end);
            l = l_end;
        }
        p = p_end;
    }
}

HazardAccess SyncModel::State::describe(const Record& r) const {
    HazardAccess a;
    a.command = commands[r.command];
    a.queue = queue_of_slot(r.queue);
    a.stage = r.stage;
    a.access = r.access;
    a.is_write = r.is_write;
    a.possible = r.possible;
    a.range = r.range;
    // An element run not resolved to one element (pending_accesses): every element at once.
    a.field = r.element_bytes ? field_names[r.field] + "*" + field_names[r.field_suffix]
                              : field_names[r.field];
    return a;
}

void SyncModel::State::emit(const Finding& f, const Record& later) {
    if (seen.count(f.key)) {
        ++stats.duplicate_hazards;
        return;
    }
    if (reports.size() >= options.max_reports) {
        // Past the cap nothing more is remembered, so memory stays bounded in a stream
        // that is all hazards; repeats are then counted here too.
        ++stats.hazards_over_cap;
        return;
    }
    seen.insert(f.key);
    HazardReport rep;
    rep.hazard = f.key.hazard;
    rep.prior = describe(f.prior);
    rep.later = describe(later);
    if (f.later_element) {
        rep.later.range = f.later_range;
        rep.later.field = field_names[f.later_field];
    }
    rep.overlap = f.overlap;
    rep.fix.kind = f.fix;
    rep.fix.src_stages = f.prior.stage;
    rep.fix.dst_stages = later.stage;
    const bool memory = f.key.hazard != HazardClass::kWriteAfterRead &&
                        !(f.key.hazard == HazardClass::kDeserializeInUse && !f.prior.is_write);
    if (memory) {
        rep.fix.src_access = f.prior.access & (all_write_accesses() | VK_ACCESS_2_SHADER_WRITE_BIT |
                                               VK_ACCESS_2_MEMORY_WRITE_BIT);
        rep.fix.dst_access = later.access;
    }
    if (f.fix == FixKind::kHostWaitAndBarrier) {
        rep.fix.dst_stages = VK_PIPELINE_STAGE_2_HOST_BIT;
        rep.fix.dst_access = VK_ACCESS_2_HOST_READ_BIT;
    }
    rep.advice = wait_advice(f.prior, later, rep);
    if (rep.advice.empty()) rep.advice = barrier_advice(f.prior, later, rep);
    reports.push_back(std::move(rep));
}

}  // namespace clastrace::replay
