// SPDX-License-Identifier: Apache-2.0
// The advice on a hazard the application meant to order with a wait that missed it
// (SyncModel::State::wait_advice): the fix names what orders the two accesses; this names the
// wait that was there, so the author finds the line to change.
#include "clastrace/common/hex.h"
#include "clastrace/replay/sync_masks.h"
#include "sync_model_internal.h"

#include <string>

namespace clastrace::replay {

namespace {

std::string submission_text(uint32_t submission) {
    return "submission " + std::to_string(submission);
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
    // whose stage mask leaves out the later access's stage.
    const Queue& q = queues[later.queue];
    for (const Import& im : q.imports) {
        if (im.signal || covered(im.own, prior.queue) <= prior.tag) continue;
        if (im.dst_scope & later.stage) continue;
        return "The wait of " + submission_text(im.submission) + " on semaphore " +
               common::hex(im.semaphore) + " follows " +
               submission_text(report.prior.command.submission) + "'s access, but at " +
               stage_names(im.wait_stages) + " only: add " + stage_names(later.stage) +
               " to the wait's stage mask (pWaitDstStageMask, VkSemaphoreSubmitInfo::stageMask).";
    }
    return {};
}

}  // namespace clastrace::replay
