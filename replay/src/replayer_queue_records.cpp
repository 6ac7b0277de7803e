// SPDX-License-Identifier: Apache-2.0
// Queue work and what the host waits for: submissions run their command buffers, waits tell
// the synchronization model what completed, acquires signal and presents wait.
#include "replayer_internal.h"

namespace clastrace::replay::detail {

// Queue work and what the host waits for: submissions run their command buffers; waits tell
// the synchronization model what completed.
bool Replay::on_queue_record(fbs::RecordBody kind, const fbs::Record& r) {
    switch (kind) {
    case fbs::RecordBody::QueueSubmit: on_submit(*r.body_as_QueueSubmit()); break;
    case fbs::RecordBody::DeviceAddressWrites:
        keep_exact_address_writes(*r.body_as_DeviceAddressWrites());
        break;
    case fbs::RecordBody::QueueWaitIdle:
        if (options_.check_hazards)
            sync_.queue_wait_idle(queue_id(r.body_as_QueueWaitIdle()->queue()));
        break;
    case fbs::RecordBody::DeviceWaitIdle:
        if (options_.check_hazards) sync_.device_wait_idle();
        break;
    case fbs::RecordBody::FenceWait: {
        const auto* w = r.body_as_FenceWait();
        if (options_.check_hazards && w->result() == VK_SUCCESS && w->fences() &&
            (w->wait_all() || w->fences()->size() == 1))
            for (uint64_t f : *w->fences()) sync_.wait_for_fence(f);
        break;
    }
    case fbs::RecordBody::FenceStatus: {
        const auto* s = r.body_as_FenceStatus();
        if (options_.check_hazards && s->result() == VK_SUCCESS) sync_.wait_for_fence(s->fence());
        break;
    }
    case fbs::RecordBody::HostSemaphoreOp: {
        const auto* h = r.body_as_HostSemaphoreOp();
        if (!options_.check_hazards || !h->semaphores() || !h->values() ||
            h->result() != VK_SUCCESS)
            break;
        const size_t n = std::min(h->semaphores()->size(), h->values()->size());
        for (size_t i = 0; i < n; ++i) {
            auto k = static_cast<flatbuffers::uoffset_t>(i);
            if (h->op() == 0)
                sync_.host_signal_semaphore(h->semaphores()->Get(k), h->values()->Get(k));
            else if (!h->wait_any() || n == 1)
                sync_.host_wait_semaphore(h->semaphores()->Get(k), h->values()->Get(k));
        }
        break;
    }
    default: return false;
    }
    return true;
}

void Replay::on_submit(const fbs::QueueSubmit& submit) {
    const uint32_t submission = static_cast<uint32_t>(submit.submission_index());
    if (submission != next_submission_)
        binary_signals_.forget_all();  // submissions left out of the trace
    next_submission_ = submission + 1;
    host_ops_ = 0;
    ++report_.counts.submissions;
    if (submit.result() != VK_SUCCESS) return;  // nothing reached the queue
    if (options_.observer) options_.observer->on_submission_begin(submission);
    const QueueId queue = queue_id(submit.queue());
    const auto* batches = submit.batches();
    const size_t batch_count = batches ? batches->size() : 0;
    uint32_t cb_index = 0;
    for (size_t b = 0; b < std::max<size_t>(batch_count, 1); ++b) {
        const fbs::SubmitBatch* batch =
            batch_count ? batches->Get(static_cast<flatbuffers::uoffset_t>(b)) : nullptr;
        std::vector<SemaphoreWait> waits;
        std::vector<SemaphoreSignal> signals;
        if (batch && batch->wait_semaphores())
            for (const fbs::SemaphoreOp* w : *batch->wait_semaphores())
                waits.push_back({w->semaphore(), w->value(),
                                 w->stage_mask()
                                     ? w->stage_mask()
                                     : StageMask(VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT)});
        if (batch && batch->signal_semaphores())
            for (const fbs::SemaphoreOp* s : *batch->signal_semaphores())
                // vkQueueSubmit signals are ALL_COMMANDS by the spec (their stage_mask is 0 or that).
                signals.push_back({s->semaphore(), s->value(),
                                   submit.version() >= 2 && s->stage_mask()
                                       ? StageMask(s->stage_mask())
                                       : StageMask(VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT)});
        check_binary_signals(submit, static_cast<uint32_t>(b), waits, signals);
        if (options_.check_hazards) sync_.begin_submission(queue, submission, waits);
        if (batch && batch->command_buffers()) {
            for (uint64_t handle : *batch->command_buffers()) {
                run_command_buffer(handle, queue, submission, cb_index, nullptr);
                ++cb_index;
            }
        }
        if (options_.check_hazards)
            sync_.end_submission(signals, b + 1 >= batch_count ? submit.fence() : 0);
        memory_.note_peak();
    }
    // Restated copies serve this submission only; the recording itself may be submitted again.
    for (const auto& [handle, count] : executions_)
        if (auto it = recorded_.find(handle);
            it != recorded_.end() && !it->second.restated.empty()) {
            uint64_t copies = 0, answers = 0;
            for (const Commands& copy : it->second.restated)
                for (const RecordedCommand& c : copy) {
                    copies += c.bytes.size();
                    for (const SnapshotAnswer& a : c.answers) answers += a.second->size();
                }
            copies = std::min(copies, it->second.bytes);
            it->second.bytes -= copies;
            recorded_bytes_ -= std::min(recorded_bytes_, copies);
            answers = std::min(answers, it->second.answer_bytes);
            it->second.answer_bytes -= answers;
            answer_bytes_ -= std::min(answer_bytes_, answers);
            it->second.restated.clear();
            it->second.filling = 0;
        }
    executions_.clear();
    // Writes kept for dispatches not replayed (left out by --ops, or of a submission that
    // failed): not kept past this submission.
    exact_address_writes_.erase(exact_address_writes_.begin(),
                                exact_address_writes_.lower_bound({submission + 1, 0, 0}));
    limit_recorded();
    // Runs ahead of commands recorded before this submission and not in it: not kept.
    if (ahead_runs_) ahead_runs_->drop_before(stream_index_);
    if (options_.observer) options_.observer->on_submission_end(submission);
}

void Replay::check_binary_signals(const fbs::QueueSubmit& submit, uint32_t batch,
                                  std::span<const SemaphoreWait> waits,
                                  std::span<const SemaphoreSignal> signals) {
    // A wait value of 0 is a binary semaphore (timeline values start above 0), as in SyncModel.
    for (const SemaphoreWait& w : waits)
        if (w.value == 0) binary_signals_.consume(w.semaphore);
    const bool v2 = submit.version() >= 2;
    const uint32_t submission = static_cast<uint32_t>(submit.submission_index());
    for (size_t i = 0; i < signals.size(); ++i) {
        if (signals[i].value != 0) continue;
        const std::string here =
            "submission " + std::to_string(submission) + " batch " + std::to_string(batch);
        const std::string earlier = binary_signals_.signal(signals[i].semaphore, here);
        if (earlier.empty()) continue;
        ReplayLocation where;
        where.sequence = sequence_;
        where.submission = submission;
        where.name = v2 ? "vkQueueSubmit2" : "vkQueueSubmit";
        where.queue = queue_id(submit.queue());  // numbered by on_submit already
        const std::string field = v2 ? "pSubmits[" + std::to_string(batch) +
                                           "].pSignalSemaphoreInfos[" + std::to_string(i) + "]"
                                     : "pSubmits[" + std::to_string(batch) +
                                           "].pSignalSemaphores[" + std::to_string(i) + "]";
        add_finding({v2 ? "VUID-vkQueueSubmit2-semaphore-03868"
                        : "VUID-vkQueueSubmit-pSignalSemaphores-00067",
                     field + ": binary semaphore " + detail::hex(signals[i].semaphore) +
                         " is signalled by " + here + " while still signalled by " + earlier +
                         " (no submission or present waited on it in between)",
                     FindingSource::kReplay, where, -1, 0});
    }
}

// Swapchain images: acquires signal, presents wait.
bool Replay::on_presentation_record(fbs::RecordBody kind, const fbs::Record& r) {
    switch (kind) {
    case fbs::RecordBody::AcquireNextImage: {
        const auto* a = r.body_as_AcquireNextImage();
        ++report_.counts.acquires;
        // VK_SUCCESS / VK_SUBOPTIMAL_KHR: the presentation engine signals the semaphore and fence.
        // vkAcquireNextImage2KHR's deviceMask is never 0 (VUID-VkAcquireNextImageInfoKHR-deviceMask-01290).
        const bool v2 = a->device_mask() != 0;
        const char* name = v2 ? "vkAcquireNextImage2KHR" : "vkAcquireNextImageKHR";
        const bool signals = a->result() == VK_SUCCESS || a->result() == VK_SUBOPTIMAL_KHR;
        if (a->semaphore()) {
            // Whatever the result, the semaphore had to be unsignalled at the call.
            const std::string here = std::string(name) + " (swapchain " +
                                     detail::hex(a->swapchain()) + ", image " +
                                     std::to_string(a->image_index()) + ")";
            const std::string earlier = signals ? binary_signals_.signal(a->semaphore(), here)
                                                : binary_signals_.signalled_by(a->semaphore());
            if (!earlier.empty()) {
                ReplayLocation where;
                where.sequence = sequence_;
                where.submission = next_submission_;
                where.name = name;
                add_finding({v2 ? "VUID-VkAcquireNextImageInfoKHR-semaphore-01288"
                                : "VUID-vkAcquireNextImageKHR-semaphore-01286",
                             std::string(v2 ? "pAcquireInfo->semaphore" : "semaphore") +
                                 ": binary semaphore " + detail::hex(a->semaphore()) +
                                 " is still signalled by " + earlier +
                                 " (no submission or present waited on it in between)",
                             FindingSource::kReplay, where, -1, 0});
            }
        }
        if (!signals) break;
        if (options_.check_hazards) sync_.acquire_signal(a->semaphore(), a->fence());
        break;
    }
    case fbs::RecordBody::QueuePresent: {
        const auto* p = r.body_as_QueuePresent();
        ++report_.counts.presents;
        if (p->wait_semaphores())
            for (uint64_t semaphore : *p->wait_semaphores()) binary_signals_.consume(semaphore);
        if (options_.check_hazards && p->wait_semaphores())
            sync_.present_wait(std::span<const uint64_t>(p->wait_semaphores()->data(),
                                                         p->wait_semaphores()->size()));
        break;
    }
    // VkFrameBoundaryEXT marks (format 1.4): frame numbers for headless programs; nothing to
    // replay (the consumer sync model reads the frame from them).
    case fbs::RecordBody::FrameBoundary: break;
    // A frame range's pre-range state (format 1.5): the prelude that follows replays like any
    // submission; the consumer model keeps it out of every frame.
    case fbs::RecordBody::PreRangeState: break;
    default: return false;
    }
    return true;
}

}  // namespace clastrace::replay::detail
