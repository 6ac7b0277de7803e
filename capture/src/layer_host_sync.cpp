// Host calls that synchronize with the device (fence, event, semaphore and idle waits and
// signals): forwarded, then recorded with their result, so replay knows which submissions had
// completed when the host next touched memory.
#include "layer_state.h"

#include <algorithm>
#include <map>

namespace clastrace::capture {
namespace {

using Kind = HostSyncRecord::Kind;

DeviceState& deviceOf(VkDevice device) { return *findDevice(dispatchKey(device)); }

void record(DeviceState& d, Kind kind, std::vector<uint64_t> handles, VkResult result, std::vector<uint64_t> values = {},
            bool waitAll = true, uint64_t timeout = 0) {
  if (!d.sink || !d.sink->active()) return;
  HostSyncRecord r;
  r.kind = kind;
  r.handles = std::move(handles);
  r.values = std::move(values);
  r.waitAll = waitAll;
  r.timeout = timeout;
  r.result = int32_t(result);
  d.sink->hostSynchronized(r);
}

template <typename Handle>
std::vector<uint64_t> ids(uint32_t count, const Handle* handles) {
  std::vector<uint64_t> out;
  for (uint32_t i = 0; i < count && handles; ++i) out.push_back(handleId(handles[i]));
  return out;
}

// A signalled fence: its submission, and every earlier one on the same queue, has completed.
void fencesCompleted(DeviceState& d, uint32_t count, const VkFence* fences) {
  std::map<VkQueue, uint64_t> completedUpTo;  // queue -> newest completed submission
  {
    std::lock_guard lock(d.timestampsMutex);
    if (d.pendingTimestampReads.empty()) return;
    for (const auto& r : d.pendingTimestampReads)
      for (uint32_t i = 0; i < count; ++i)
        if (r.fence && r.fence == handleId(fences[i]))
          completedUpTo[r.queue] = std::max(completedUpTo[r.queue], r.submissionIndex);
  }
  if (completedUpTo.empty()) return;
  readCompletedTimestamps(d, [&](const DeviceState::PendingTimestampRead& r) {
    auto it = completedUpTo.find(r.queue);
    return it != completedUpTo.end() && r.submissionIndex <= it->second;
  });
}

VKAPI_ATTR VkResult VKAPI_CALL SetEvent(VkDevice device, VkEvent event) {
  DeviceState& d = deviceOf(device);
  VkResult result = d.next.SetEvent(device, event);
  record(d, Kind::EventSet, {handleId(event)}, result);
  return result;
}
VKAPI_ATTR VkResult VKAPI_CALL ResetEvent(VkDevice device, VkEvent event) {
  DeviceState& d = deviceOf(device);
  VkResult result = d.next.ResetEvent(device, event);
  record(d, Kind::EventReset, {handleId(event)}, result);
  return result;
}
VKAPI_ATTR VkResult VKAPI_CALL GetEventStatus(VkDevice device, VkEvent event) {
  DeviceState& d = deviceOf(device);
  VkResult result = d.next.GetEventStatus(device, event);
  record(d, Kind::EventStatus, {handleId(event)}, result);
  return result;
}

VKAPI_ATTR VkResult VKAPI_CALL WaitForFences(VkDevice device, uint32_t count, const VkFence* fences, VkBool32 waitAll,
                                             uint64_t timeout) {
  DeviceState& d = deviceOf(device);
  VkResult result = d.next.WaitForFences(device, count, fences, waitAll, timeout);
  if (result == VK_SUCCESS && (waitAll || count == 1)) fencesCompleted(d, count, fences);
  record(d, Kind::FenceWait, ids(count, fences), result, {}, waitAll == VK_TRUE, timeout);
  return result;
}
VKAPI_ATTR VkResult VKAPI_CALL ResetFences(VkDevice device, uint32_t count, const VkFence* fences) {
  DeviceState& d = deviceOf(device);
  VkResult result = d.next.ResetFences(device, count, fences);
  if (result == VK_SUCCESS) record(d, Kind::FenceReset, ids(count, fences), result);
  return result;
}
VKAPI_ATTR VkResult VKAPI_CALL GetFenceStatus(VkDevice device, VkFence fence) {
  DeviceState& d = deviceOf(device);
  VkResult result = d.next.GetFenceStatus(device, fence);
  if (result == VK_SUCCESS) fencesCompleted(d, 1, &fence);
  record(d, Kind::FenceStatus, {handleId(fence)}, result);
  return result;
}

VKAPI_ATTR VkResult VKAPI_CALL QueueWaitIdle(VkQueue queue) {
  DeviceState& d = *findDevice(dispatchKey(queue));
  VkResult result = d.next.QueueWaitIdle(queue);
  if (result == VK_SUCCESS)
    readCompletedTimestamps(d, [queue](const DeviceState::PendingTimestampRead& r) { return r.queue == queue; });
  record(d, Kind::QueueWaitIdle, {handleId(queue)}, result);
  return result;
}
VKAPI_ATTR VkResult VKAPI_CALL DeviceWaitIdle(VkDevice device) {
  DeviceState& d = deviceOf(device);
  VkResult result = d.next.DeviceWaitIdle(device);
  if (result == VK_SUCCESS) readCompletedTimestamps(d, [](const DeviceState::PendingTimestampRead&) { return true; });
  record(d, Kind::DeviceWaitIdle, {}, result);
  return result;
}

VkResult signalSemaphore(VkDevice device, const VkSemaphoreSignalInfo* info, PFN_vkSignalSemaphore next) {
  DeviceState& d = deviceOf(device);
  VkResult result = next(device, info);
  record(d, Kind::SemaphoreSignal, {handleId(info->semaphore)}, result, {info->value});
  return result;
}
VKAPI_ATTR VkResult VKAPI_CALL SignalSemaphore(VkDevice device, const VkSemaphoreSignalInfo* info) {
  return signalSemaphore(device, info, deviceOf(device).next.SignalSemaphore);
}
VKAPI_ATTR VkResult VKAPI_CALL SignalSemaphoreKHR(VkDevice device, const VkSemaphoreSignalInfo* info) {
  return signalSemaphore(device, info, deviceOf(device).next.SignalSemaphoreKHR);
}

VkResult waitSemaphores(VkDevice device, const VkSemaphoreWaitInfo* info, uint64_t timeout, PFN_vkWaitSemaphores next) {
  DeviceState& d = deviceOf(device);
  VkResult result = next(device, info, timeout);
  std::vector<uint64_t> values;
  for (uint32_t i = 0; i < info->semaphoreCount && info->pValues; ++i) values.push_back(info->pValues[i]);
  record(d, Kind::SemaphoreWait, ids(info->semaphoreCount, info->pSemaphores), result, std::move(values),
         !(info->flags & VK_SEMAPHORE_WAIT_ANY_BIT), timeout);
  return result;
}
VKAPI_ATTR VkResult VKAPI_CALL WaitSemaphores(VkDevice device, const VkSemaphoreWaitInfo* info, uint64_t timeout) {
  return waitSemaphores(device, info, timeout, deviceOf(device).next.WaitSemaphores);
}
VKAPI_ATTR VkResult VKAPI_CALL WaitSemaphoresKHR(VkDevice device, const VkSemaphoreWaitInfo* info, uint64_t timeout) {
  return waitSemaphores(device, info, timeout, deviceOf(device).next.WaitSemaphoresKHR);
}

}  // namespace

PFN_vkVoidFunction hostSyncHook(const char* name) {
#define HOOK(fn) {"vk" #fn, (PFN_vkVoidFunction)fn}
  static const std::map<std::string, PFN_vkVoidFunction, std::less<>> hooks = {
      HOOK(SetEvent),      HOOK(ResetEvent),     HOOK(GetEventStatus),     HOOK(WaitForFences),
      HOOK(ResetFences),   HOOK(GetFenceStatus), HOOK(QueueWaitIdle),      HOOK(DeviceWaitIdle),
      HOOK(SignalSemaphore), HOOK(SignalSemaphoreKHR), HOOK(WaitSemaphores), HOOK(WaitSemaphoresKHR),
  };
#undef HOOK
  auto it = hooks.find(name);
  return it == hooks.end() ? nullptr : it->second;
}

}  // namespace clastrace::capture
