// SPDX-License-Identifier: Apache-2.0
// Queue submissions: recorded with their semaphores and fence, and announced to the pause
// worker (inside the application's call, so the order per queue is the queue's order).
#include "command_buffer_log.h"
#include "host_write_device_writes.h"
#include "layer_pre_range.h"
#include "layer_state.h"

#include <algorithm>
#include <chrono>
#include <deque>
#include <map>

namespace clastrace::capture {
namespace {

struct PendingPauses {
    uint64_t command_buffer;
    std::vector<PausePoint> pauses;
    bool simultaneous_use = false;
    VkQueryPool timestamp_pool =
        VK_NULL_HANDLE;  // the layer's timestamps of this recording, if any
    uint32_t timestamps = 0;
    uint64_t timestamp_read_pause_id = 0;
};

PendingPauses pauses_of(DeviceState& d, VkCommandBuffer cb) {
    std::lock_guard lock(d.command_buffers_mutex);
    auto it = d.command_buffers.find(cb);
    if (it == d.command_buffers.end()) return {handle_id(cb), {}, false};
    const CommandBufferLog& log = *it->second;
    PendingPauses pending{handle_id(cb),
                          log.pauses,
                          (log.recorded.usage & VK_COMMAND_BUFFER_USAGE_SIMULTANEOUS_USE_BIT) != 0,
                          log.timestamp_pool,
                          log.timestamps_written,
                          log.timestamp_read_pause_id};
    if (pending.simultaneous_use)
        for (PausePoint& pause : pending.pauses) pause.shared = true;
    return pending;
}

// Everything the worker must expect from one submission, gathered before the driver call so
// no command buffer can be re-recorded in between.
struct SubmissionPlan {
    SubmissionRecord record;
    std::vector<PendingPauses> pauses;
    bool capture = false;
    bool before_range = false;   // its structure builds are read for the pre-range state
    uint64_t prelude_index = 0;  // the first captured one: the pre-range prelude's index, if due
};

void announce(DeviceState& d, VkQueue queue, SubmissionPlan& plan) {
    if (!d.pauses) return;
    // A simultaneous-use command buffer listed twice runs its pauses twice: number them so each
    // execution is captured on its own.
    std::map<std::pair<uint64_t, PausePhase>, uint32_t> executions;
    for (PendingPauses& p : plan.pauses)
        for (PausePoint& pause : p.pauses)
            pause.occurrence = executions[{pause.pause_id, pause.phase}]++;
    if (!plan.before_range) {
        for (PendingPauses& p : plan.pauses)
            d.pauses->expect(queue, plan.record.index, plan.capture, p.command_buffer, p.pauses);
        return;
    }
    // Before the range only the structure builds and copies are read (layer_pre_range.h). The
    // pre-range store learns them before the worker may take their captures.
    std::vector<const PausePoint*> pre_range;
    std::vector<bool> read;
    for (const PendingPauses& p : plan.pauses)
        for (const PausePoint& pause : p.pauses) {
            read.push_back(produces_pre_range_state(pause));
            if (read.back()) pre_range.push_back(&pause);
        }
    note_pre_range_submission(d, plan.record, pre_range);
    size_t next = 0;
    for (PendingPauses& p : plan.pauses)
        for (const PausePoint& pause : p.pauses)
            d.pauses->expect(queue, plan.record.index, read[next++], p.command_buffer, {pause});
}

// Executions of one command buffer on two queues would share its pause events (pause_worker.h,
// shared_pause_tracker.h). Before the driver sees a submission whose pauses may run on several
// queues, wait until no other queue uses those events; the returned lock is held until the
// worker expects this submission's pauses. Where the wait gives up, the submission goes ahead
// and carries a note (CaptureFinding) that its captures may be wrong.
std::unique_lock<std::mutex> admit_shared_pauses(DeviceState& d, VkQueue queue,
                                                 SubmissionPlan& plan) {
    if (!d.pauses) return {};
    std::vector<uint64_t> releases;
    std::vector<uint64_t> command_buffers;
    for (const PendingPauses& p : plan.pauses)
        for (const PausePoint& pause : p.pauses)
            if (pause.shared) {
                releases.push_back(handle_id(pause.release));
                if (command_buffers.empty() || command_buffers.back() != p.command_buffer)
                    command_buffers.push_back(p.command_buffer);
            }
    if (releases.empty()) return {};
    // The other queue may wait for something the application does only after this call returns
    // (a host-set event, a timeline value signalled later): then the wait gives up, and says so.
    const std::chrono::milliseconds patience{layer_config().shared_wait_milliseconds};
    std::unique_lock lock(d.shared_pauses_mutex);
    if (d.pauses->wait_until_free(queue, releases, patience)) return lock;
    log_message(
        LogLevel::kError,
        "submission %llu: a simultaneous-use command buffer is still running on another queue "
        "after %lld ms; its executions share the layer's pause events, so the captures of this "
        "submission may "
        "be wrong",
        (unsigned long long)application_submission(plan.record.index), (long long)patience.count());
    for (uint64_t cb : command_buffers)
        plan.record.notes.push_back(
            {cb, "CLASTRACE-capture-concurrent-execution",
             "this command buffer (or a simultaneous-use secondary it executes) was still running "
             "its captured commands on another queue when this submission was made, and the layer "
             "gave up waiting for it: both executions used the same pause events, so the memory "
             "captured for either may have been read at the wrong point"});
    return lock;
}

SubmissionPlan plan_for(DeviceState& d, VkQueue queue, VkFence fence, bool synchronization2) {
    SubmissionPlan plan;
    plan.record.index = next_submission_index();
    plan.record.queue = handle_id(queue);
    {
        std::lock_guard lock(d.queues_mutex);
        if (auto f = d.queue_families.find(queue); f != d.queue_families.end())
            plan.record.queue_family = f->second;
        if (auto i = d.queue_indices.find(queue); i != d.queue_indices.end())
            plan.record.queue_index = i->second;
    }
    plan.record.fence = handle_id(fence);
    plan.record.synchronization2 = synchronization2;
    const uint64_t counted = application_submission(plan.record.index);
    plan.capture = d.sink && layer_config().submit_range.contains(counted) &&
                   layer_config().frame_range.contains(current_frame());
    plan.before_range = !plan.capture && before_frame_range(d, counted);
    if (plan.capture && pre_range_prelude_due(d)) {  // the prelude goes first
        plan.prelude_index = plan.record.index;
        plan.record.index = index_after_prelude(plan.prelude_index);
    }
    return plan;
}

// The executions whose timestamps the trace waits for: read once they are known complete.
void expect_timestamps(DeviceState& d, VkQueue queue, const SubmissionPlan& plan) {
    if (!plan.capture) return;
    std::map<uint64_t, uint32_t> executions;  // read id -> executions in this submission
    std::lock_guard lock(d.timestamps_mutex);
    for (const PendingPauses& p : plan.pauses)
        if (p.timestamp_pool && p.timestamps)
            d.pending_timestamp_reads.push_back(
                {queue, plan.record.fence, plan.record.index, p.command_buffer, p.timestamp_pool,
                 p.timestamps, p.timestamp_read_pause_id, executions[p.timestamp_read_pause_id]++});
}

// CLASTRACE_RAY_CHECK: the top levels this submission built (or updated), NV or KHR, get their
// rays traced once it completed.
void check_rays(DeviceState& d, VkQueue queue, const SubmissionPlan& plan) {
    if (!plan.capture || layer_config().ray_check_rays == 0) return;
    std::vector<uint64_t> top_levels;
    auto add = [&](uint64_t top_level) {
        if (std::find(top_levels.begin(), top_levels.end(), top_level) == top_levels.end())
            top_levels.push_back(top_level);
    };
    for (const PendingPauses& p : plan.pauses)
        for (const PausePoint& pause : p.pauses) {
            if (pause.build_nv &&
                pause.build_nv->type == VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV)
                add(pause.build_nv->dst);
            if (pause.build_khr)
                for (const KhrBuildInfo& info : pause.build_khr->infos)
                    if (info.info.type == VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR)
                        add(handle_id(info.info.dstAccelerationStructure));
        }
    run_ray_checks(d, queue, plan.record.index, top_levels);
}

// Host writes (host_write_watch.h): before the driver call, so the hashes are of what the host
// wrote before it submitted. A submission outside the captured range is still followed for what
// its commands may write, so those writes are not taken for the host's.
void watch_host_writes(DeviceState& d, const SubmissionPlan& plan) {
    if (!d.capturing_now() || !layer_config().host_writes) return;
    std::vector<const PausePoint*> pauses;
    if (plan.capture)
        for (const PendingPauses& p : plan.pauses)
            for (const PausePoint& pause : p.pauses) pauses.push_back(&pause);
    std::vector<uint64_t> command_buffers;
    for (const SubmitBatch& b : plan.record.batches)
        command_buffers.insert(command_buffers.end(), b.command_buffers.begin(),
                               b.command_buffers.end());
    d.host_writes.submitting(d, plan.record, pauses, device_writes_of(d, command_buffers));
}

// VkFrameBoundaryEXT on the infos of one submission call (layer_frame_boundary.cpp): found
// before the driver call, hidden from a driver without the extension during it, recorded after
// the submission's own record.
class SubmittedFrameBoundaries {
public:
    template <typename Info>
    SubmittedFrameBoundaries(const DeviceState& d, const Info* infos, uint32_t count) {
        for (uint32_t i = 0; i < count; ++i)
            if (const VkFrameBoundaryEXT* b = find_frame_boundary(infos[i].pNext)) {
                found_.push_back({i, b});
                if (d.frame_boundary_served)
                    hidden_.emplace_back(&infos[i], VK_STRUCTURE_TYPE_FRAME_BOUNDARY_EXT);
            }
    }
    // The driver call returned: the application's chains are whole again.
    void restore() { hidden_.clear(); }
    void record(DeviceState& d, VkQueue queue, FrameBoundaryCarrier carrier, uint64_t submission) {
        for (const auto& [batch, boundary] : found_)
            frame_boundary_marked(d, queue, *boundary, carrier, submission, batch, frame_);
    }

private:
    uint64_t frame_ = current_frame();
    std::vector<std::pair<uint32_t, const VkFrameBoundaryEXT*>> found_;
    std::deque<ChainUnlink> hidden_;
};

// The driver's `submit` of a planned submission, between the layer's work before it (host
// writes, shared pauses, frame boundaries hidden from a driver that lacks them) and after it
// (the worker told, the prelude, the record, frame boundaries, ray checks).
template <typename Info, typename DriverSubmit>
VkResult submit_planned(DeviceState& d, VkQueue queue, SubmissionPlan& plan, const Info* p_submits,
                        uint32_t submit_count, FrameBoundaryCarrier carrier,
                        DriverSubmit&& submit) {
    if (plan.capture) refresh_consumer_structures(d, plan.record);
    watch_host_writes(d, plan);
    auto admitted = admit_shared_pauses(d, queue, plan);
    SubmittedFrameBoundaries boundaries(d, p_submits, submit_count);
    VkResult result = submit();
    boundaries.restore();
    if (result != VK_SUCCESS) {
        d.host_writes.submit_failed(plan.record.index);
        return result;
    }
    announce(d, queue, plan);
    if (admitted.owns_lock())
        admitted.unlock();  // the worker tracks this submission's shared pauses now
    expect_timestamps(d, queue, plan);
    if (plan.prelude_index) write_pre_range_prelude(d, plan.record, plan.prelude_index);
    if (plan.capture) d.sink->queue_submitted(plan.record);
    boundaries.record(d, queue, carrier, application_submission(plan.record.index));
    check_rays(d, queue, plan);
    return result;
}

VKAPI_ATTR VkResult VKAPI_CALL QueueSubmit(VkQueue queue, uint32_t submit_count,
                                           const VkSubmitInfo* p_submits, VkFence fence) {
    DeviceState& d = *find_device(dispatch_key(queue));
    SubmissionPlan plan = plan_for(d, queue, fence, false);
    for (uint32_t s = 0; s < submit_count; ++s) {
        const VkSubmitInfo& submit = p_submits[s];
        const VkTimelineSemaphoreSubmitInfo* timeline = nullptr;
        for (auto* n = (const VkBaseInStructure*)submit.pNext; n; n = n->pNext)
            if (n->sType == VK_STRUCTURE_TYPE_TIMELINE_SEMAPHORE_SUBMIT_INFO)
                timeline = (const VkTimelineSemaphoreSubmitInfo*)n;
        SubmitBatch batch;
        for (uint32_t i = 0; i < submit.waitSemaphoreCount; ++i) {
            uint64_t value =
                timeline && i < timeline->waitSemaphoreValueCount && timeline->pWaitSemaphoreValues
                    ? timeline->pWaitSemaphoreValues[i]
                    : 0;
            batch.waits.push_back(
                {handle_id(submit.pWaitSemaphores[i]), value, submit.pWaitDstStageMask[i]});
        }
        for (uint32_t i = 0; i < submit.signalSemaphoreCount; ++i) {
            uint64_t value = timeline && i < timeline->signalSemaphoreValueCount &&
                                     timeline->pSignalSemaphoreValues
                                 ? timeline->pSignalSemaphoreValues[i]
                                 : 0;
            batch.signals.push_back({handle_id(submit.pSignalSemaphores[i]), value,
                                     VK_PIPELINE_STAGE_ALL_COMMANDS_BIT});
        }
        for (uint32_t i = 0; i < submit.commandBufferCount; ++i) {
            batch.command_buffers.push_back(handle_id(submit.pCommandBuffers[i]));
            plan.pauses.push_back(pauses_of(d, submit.pCommandBuffers[i]));
        }
        plan.record.batches.push_back(std::move(batch));
    }
    return submit_planned(d, queue, plan, p_submits, submit_count, FrameBoundaryCarrier::kSubmit,
                          [&] {
                              return d.next.QueueSubmit(queue, submit_count, p_submits, fence);
                          });
}

VkResult queue_submit2(VkQueue queue, uint32_t submit_count, const VkSubmitInfo2* p_submits,
                       VkFence fence, PFN_vkQueueSubmit2 next) {
    DeviceState& d = *find_device(dispatch_key(queue));
    SubmissionPlan plan = plan_for(d, queue, fence, true);
    for (uint32_t s = 0; s < submit_count; ++s) {
        const VkSubmitInfo2& submit = p_submits[s];
        SubmitBatch batch;
        for (uint32_t i = 0; i < submit.waitSemaphoreInfoCount; ++i) {
            const auto& w = submit.pWaitSemaphoreInfos[i];
            batch.waits.push_back({handle_id(w.semaphore), w.value, w.stageMask});
        }
        for (uint32_t i = 0; i < submit.signalSemaphoreInfoCount; ++i) {
            const auto& g = submit.pSignalSemaphoreInfos[i];
            batch.signals.push_back({handle_id(g.semaphore), g.value, g.stageMask});
        }
        for (uint32_t i = 0; i < submit.commandBufferInfoCount; ++i) {
            VkCommandBuffer cb = submit.pCommandBufferInfos[i].commandBuffer;
            batch.command_buffers.push_back(handle_id(cb));
            plan.pauses.push_back(pauses_of(d, cb));
        }
        plan.record.batches.push_back(std::move(batch));
    }
    return submit_planned(d, queue, plan, p_submits, submit_count, FrameBoundaryCarrier::kSubmit2,
                          [&] { return next(queue, submit_count, p_submits, fence); });
}

VKAPI_ATTR VkResult VKAPI_CALL QueueSubmit2(VkQueue queue, uint32_t count,
                                            const VkSubmitInfo2* submits, VkFence fence) {
    return queue_submit2(queue, count, submits, fence,
                         find_device(dispatch_key(queue))->next.QueueSubmit2);
}
VKAPI_ATTR VkResult VKAPI_CALL QueueSubmit2KHR(VkQueue queue, uint32_t count,
                                               const VkSubmitInfo2* submits, VkFence fence) {
    return queue_submit2(queue, count, submits, fence,
                         find_device(dispatch_key(queue))->next.QueueSubmit2KHR);
}

}  // namespace

PFN_vkVoidFunction submit_hook(const char* name) {
    static const std::map<std::string, PFN_vkVoidFunction, std::less<>> kHooks = {
        {"vkQueueSubmit", (PFN_vkVoidFunction)QueueSubmit},
        {"vkQueueSubmit2", (PFN_vkVoidFunction)QueueSubmit2},
        {"vkQueueSubmit2KHR", (PFN_vkVoidFunction)QueueSubmit2KHR},
    };
    auto it = kHooks.find(name);
    return it == kHooks.end() ? nullptr : it->second;
}

}  // namespace clastrace::capture
