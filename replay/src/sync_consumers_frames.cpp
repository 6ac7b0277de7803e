// SPDX-License-Identifier: Apache-2.0
// Frames of the trace and the frame-level advice on consumer hazards (sync_consumers.h).
#include "sync_consumers.h"

#include <algorithm>
#include <string>

namespace clastrace::replay::detail {

bool is_consumer_read(const HazardAccess& access) {
    return !access.is_write && access.field.starts_with(kConsumerField);
}

void FrameBoundaries::on_boundary(uint64_t frame, uint32_t submissions_before) {
    ends_.emplace_back(submissions_before, frame);
}

std::optional<uint64_t> FrameBoundaries::frame_of(uint32_t submission) const {
    if (ends_.empty() || prelude_ == submission) return std::nullopt;
    // The first boundary after the submission ends its frame; past the last one, the next frame.
    auto it = std::upper_bound(ends_.begin(), ends_.end(), submission,
                               [](uint32_t s, const auto& end) { return s < end.first; });
    if (it != ends_.end()) return it->second;
    return ends_.back().second + 1;
}

namespace {

// "frame 2", or in a trace without frame boundaries "submission 7".
std::string frame_text(const HazardAccess& a) {
    return a.frame ? "frame " + std::to_string(*a.frame)
                   : "submission " + std::to_string(a.command.submission);
}

// The advice for a hazard between a consumer and a command of another submission; within one
// submission the barrier the fix names is the whole answer.
std::string consumer_advice(const HazardReport& h) {
    const bool prior_reads = is_consumer_read(h.prior), later_reads = is_consumer_read(h.later);
    if ((!prior_reads && !later_reads) || h.prior.command.submission == h.later.command.submission)
        return {};
    if (prior_reads && h.later.is_write && h.hazard == HazardClass::kWriteAfterRead)
        return "The rays of " + frame_text(h.prior) + " may still be reading the structure when " +
               frame_text(h.later) + " overwrites it: wait for the fence of " +
               frame_text(h.prior) +
               " (vkWaitForFences) before rebuilding, or double-buffer the pool (one set of "
               "structures per frame in flight).";
    if (later_reads && h.prior.is_write)
        return "The structure was written in " + frame_text(h.prior) + " and read in " +
               frame_text(h.later) +
               ": the barrier (or semaphore) must follow the write, in its submission.";
    return {};
}

}  // namespace

void annotate_consumer_hazards(std::vector<HazardReport>& hazards, const FrameBoundaries& frames) {
    for (HazardReport& h : hazards) {
        if (h.prior.queue != kHostQueue)
            h.prior.frame = frames.frame_of(h.prior.command.submission);
        if (h.later.queue != kHostQueue)
            h.later.frame = frames.frame_of(h.later.command.submission);
        if (std::string advice = consumer_advice(h); !advice.empty()) h.advice = std::move(advice);
    }
}

}  // namespace clastrace::replay::detail
