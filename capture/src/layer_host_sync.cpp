// SPDX-License-Identifier: Apache-2.0
// Host calls that synchronize with the device (fence, event, semaphore and idle waits and
// signals): forwarded, then recorded with their result, so replay knows which submissions had
// completed when the host next touched memory.
#include "layer_pre_range.h"
#include "layer_state.h"

#include <algorithm>
#include <functional>
#include <map>

namespace clastrace::capture {
namespace {

using Kind = HostSyncRecord::Kind;

DeviceState& device_of(VkDevice device) { return *find_device(dispatch_key(device)); }

void record(DeviceState& d, Kind kind, std::vector<uint64_t> handles, VkResult result,
            std::vector<uint64_t> values = {}, bool wait_all = true, uint64_t timeout = 0) {
    if (!d.sink || !d.sink->active()) return;
    HostSyncRecord r;
    r.kind = kind;
    r.handles = std::move(handles);
    r.values = std::move(values);
    r.wait_all = wait_all;
    r.timeout = timeout;
    r.result = int32_t(result);
    d.sink->host_synchronized(r);
}

template <typename Handle>
std::vector<uint64_t> ids(uint32_t count, const Handle* handles) {
    std::vector<uint64_t> out;
    for (uint32_t i = 0; i < count && handles; ++i) out.push_back(handle_id(handles[i]));
    return out;
}

// A signalled fence: its submission, and every earlier one on the same queue, has completed.
void fences_completed(DeviceState& d, uint32_t count, const VkFence* fences) {
    std::map<VkQueue, uint64_t> completed_up_to;  // queue -> newest completed submission
    {
        std::lock_guard lock(d.timestamps_mutex);
        if (d.pending_timestamp_reads.empty()) return;
        for (const auto& r : d.pending_timestamp_reads)
            for (uint32_t i = 0; i < count; ++i)
                if (r.fence && r.fence == handle_id(fences[i]))
                    completed_up_to[r.queue] =
                        std::max(completed_up_to[r.queue], r.submission_index);
    }
    if (completed_up_to.empty()) return;
    read_completed_timestamps(d, [&](const DeviceState::PendingTimestampRead& r) {
        auto it = completed_up_to.find(r.queue);
        return it != completed_up_to.end() && r.submission_index <= it->second;
    });
}

// A wait that ordered watched submissions: their host writes go out ahead of the wait's record.
void look_for_host_writes(DeviceState& d,
                          const std::function<bool(const HostWriteWatch::Submission&)>& orders) {
    if (d.capturing_now() && layer_config().host_writes) d.host_writes.waited(d, orders);
}

// Whether a host wait for `info`'s values (all of them) has seen one of `signals` happen.
bool signals_reached(const std::vector<SemaphoreUse>& signals, const VkSemaphoreWaitInfo& info) {
    for (uint32_t i = 0; i < info.semaphoreCount; ++i)
        for (const SemaphoreUse& signal : signals)
            if (signal.semaphore == handle_id(info.pSemaphores[i]) &&
                signal.value <= info.pValues[i])
                return true;
    return false;
}

VKAPI_ATTR VkResult VKAPI_CALL SetEvent(VkDevice device, VkEvent event) {
    DeviceState& d = device_of(device);
    VkResult result = d.next.SetEvent(device, event);
    record(d, Kind::kEventSet, {handle_id(event)}, result);
    return result;
}
VKAPI_ATTR VkResult VKAPI_CALL ResetEvent(VkDevice device, VkEvent event) {
    DeviceState& d = device_of(device);
    VkResult result = d.next.ResetEvent(device, event);
    record(d, Kind::kEventReset, {handle_id(event)}, result);
    return result;
}
VKAPI_ATTR VkResult VKAPI_CALL GetEventStatus(VkDevice device, VkEvent event) {
    DeviceState& d = device_of(device);
    VkResult result = d.next.GetEventStatus(device, event);
    record(d, Kind::kEventStatus, {handle_id(event)}, result);
    return result;
}

VKAPI_ATTR VkResult VKAPI_CALL WaitForFences(VkDevice device, uint32_t count, const VkFence* fences,
                                             VkBool32 wait_all, uint64_t timeout) {
    DeviceState& d = device_of(device);
    VkResult result = d.next.WaitForFences(device, count, fences, wait_all, timeout);
    if (result == VK_SUCCESS && (wait_all || count == 1)) {
        fences_completed(d, count, fences);
        note_pre_range_wait(d, [&](const PreRangeSubmission& s) {
            return s.fence && std::any_of(fences, fences + count,
                                          [&](VkFence f) { return handle_id(f) == s.fence; });
        });
        look_for_host_writes(d, [&](const HostWriteWatch::Submission& s) {
            return s.fence && std::any_of(fences, fences + count,
                                          [&](VkFence f) { return handle_id(f) == s.fence; });
        });
    }
    record(d, Kind::kFenceWait, ids(count, fences), result, {}, wait_all == VK_TRUE, timeout);
    return result;
}
VKAPI_ATTR VkResult VKAPI_CALL ResetFences(VkDevice device, uint32_t count, const VkFence* fences) {
    DeviceState& d = device_of(device);
    VkResult result = d.next.ResetFences(device, count, fences);
    if (result == VK_SUCCESS) record(d, Kind::kFenceReset, ids(count, fences), result);
    return result;
}
VKAPI_ATTR VkResult VKAPI_CALL GetFenceStatus(VkDevice device, VkFence fence) {
    DeviceState& d = device_of(device);
    VkResult result = d.next.GetFenceStatus(device, fence);
    if (result == VK_SUCCESS) {
        fences_completed(d, 1, &fence);
        note_pre_range_wait(d, [&](const PreRangeSubmission& s) {
            return s.fence && s.fence == handle_id(fence);
        });
        look_for_host_writes(d, [&](const HostWriteWatch::Submission& s) {
            return s.fence && s.fence == handle_id(fence);
        });
    }
    record(d, Kind::kFenceStatus, {handle_id(fence)}, result);
    return result;
}

VKAPI_ATTR VkResult VKAPI_CALL QueueWaitIdle(VkQueue queue) {
    DeviceState& d = *find_device(dispatch_key(queue));
    VkResult result = d.next.QueueWaitIdle(queue);
    if (result == VK_SUCCESS)
        note_pre_range_wait(d, [&](const PreRangeSubmission& s) {
            return s.queue == handle_id(queue);
        });
    if (result == VK_SUCCESS)
        read_completed_timestamps(d, [queue](const DeviceState::PendingTimestampRead& r) {
            return r.queue == queue;
        });
    if (result == VK_SUCCESS)
        look_for_host_writes(d, [&](const HostWriteWatch::Submission& s) {
            return s.queue == handle_id(queue);
        });
    record(d, Kind::kQueueWaitIdle, {handle_id(queue)}, result);
    return result;
}
VKAPI_ATTR VkResult VKAPI_CALL DeviceWaitIdle(VkDevice device) {
    DeviceState& d = device_of(device);
    VkResult result = d.next.DeviceWaitIdle(device);
    if (result == VK_SUCCESS)
        note_pre_range_wait(d, [](const PreRangeSubmission&) { return true; });
    if (result == VK_SUCCESS)
        read_completed_timestamps(d, [](const DeviceState::PendingTimestampRead&) { return true; });
    if (result == VK_SUCCESS)
        look_for_host_writes(d, [](const HostWriteWatch::Submission&) { return true; });
    record(d, Kind::kDeviceWaitIdle, {}, result);
    return result;
}

VkResult signal_semaphore(VkDevice device, const VkSemaphoreSignalInfo* info,
                          PFN_vkSignalSemaphore next) {
    DeviceState& d = device_of(device);
    VkResult result = next(device, info);
    record(d, Kind::kSemaphoreSignal, {handle_id(info->semaphore)}, result, {info->value});
    return result;
}
VKAPI_ATTR VkResult VKAPI_CALL SignalSemaphore(VkDevice device, const VkSemaphoreSignalInfo* info) {
    return signal_semaphore(device, info, device_of(device).next.SignalSemaphore);
}
VKAPI_ATTR VkResult VKAPI_CALL SignalSemaphoreKHR(VkDevice device,
                                                  const VkSemaphoreSignalInfo* info) {
    return signal_semaphore(device, info, device_of(device).next.SignalSemaphoreKHR);
}

VkResult wait_semaphores(VkDevice device, const VkSemaphoreWaitInfo* info, uint64_t timeout,
                         PFN_vkWaitSemaphores next) {
    DeviceState& d = device_of(device);
    VkResult result = next(device, info, timeout);
    const bool all = !(info->flags & VK_SEMAPHORE_WAIT_ANY_BIT) || info->semaphoreCount == 1;
    if (result == VK_SUCCESS && all && info->pValues) {
        note_pre_range_wait(d, [&](const PreRangeSubmission& s) {
            return signals_reached(s.last_signals, *info);
        });
        look_for_host_writes(d, [&](const HostWriteWatch::Submission& s) {
            return signals_reached(s.signals, *info);
        });
    }
    std::vector<uint64_t> values;
    for (uint32_t i = 0; i < info->semaphoreCount && info->pValues; ++i)
        values.push_back(info->pValues[i]);
    record(d, Kind::kSemaphoreWait, ids(info->semaphoreCount, info->pSemaphores), result,
           std::move(values), !(info->flags & VK_SEMAPHORE_WAIT_ANY_BIT), timeout);
    return result;
}
VKAPI_ATTR VkResult VKAPI_CALL WaitSemaphores(VkDevice device, const VkSemaphoreWaitInfo* info,
                                              uint64_t timeout) {
    return wait_semaphores(device, info, timeout, device_of(device).next.WaitSemaphores);
}
VKAPI_ATTR VkResult VKAPI_CALL WaitSemaphoresKHR(VkDevice device, const VkSemaphoreWaitInfo* info,
                                                 uint64_t timeout) {
    return wait_semaphores(device, info, timeout, device_of(device).next.WaitSemaphoresKHR);
}

}  // namespace

PFN_vkVoidFunction host_sync_hook(const char* name) {
#define HOOK(fn) \
    { "vk" #fn, (PFN_vkVoidFunction)fn }
    static const std::map<std::string, PFN_vkVoidFunction, std::less<>> kHooks = {
        HOOK(SetEvent),           HOOK(ResetEvent),     HOOK(GetEventStatus),
        HOOK(WaitForFences),      HOOK(ResetFences),    HOOK(GetFenceStatus),
        HOOK(QueueWaitIdle),      HOOK(DeviceWaitIdle), HOOK(SignalSemaphore),
        HOOK(SignalSemaphoreKHR), HOOK(WaitSemaphores), HOOK(WaitSemaphoresKHR),
    };
#undef HOOK
    auto it = kHooks.find(name);
    return it == kHooks.end() ? nullptr : it->second;
}

}  // namespace clastrace::capture
