// Queue submissions: recorded with their semaphores and fence, and announced to the pause
// worker (inside the application's call, so the order per queue is the queue's order).
#include "command_buffer_log.h"
#include "layer_state.h"

#include <algorithm>
#include <chrono>
#include <map>

namespace clastrace::capture {
namespace {

struct PendingPauses {
  uint64_t commandBuffer;
  std::vector<PausePoint> pauses;
  bool simultaneousUse = false;
  VkQueryPool timestampPool = VK_NULL_HANDLE;  // the layer's timestamps of this recording, if any
  uint32_t timestamps = 0;
  uint64_t timestampReadPauseId = 0;
};

PendingPauses pausesOf(DeviceState& d, VkCommandBuffer cb) {
  std::lock_guard lock(d.commandBuffersMutex);
  auto it = d.commandBuffers.find(cb);
  if (it == d.commandBuffers.end()) return {handleId(cb), {}, false};
  const CommandBufferLog& log = *it->second;
  PendingPauses pending{handleId(cb), log.pauses, (log.recorded.usage & VK_COMMAND_BUFFER_USAGE_SIMULTANEOUS_USE_BIT) != 0,
                        log.timestampPool, log.timestampsWritten, log.timestampReadPauseId};
  if (pending.simultaneousUse)
    for (PausePoint& pause : pending.pauses) pause.shared = true;
  return pending;
}

// Everything the worker must expect from one submission, gathered before the driver call so
// no command buffer can be re-recorded in between.
struct SubmissionPlan {
  SubmissionRecord record;
  std::vector<PendingPauses> pauses;
  bool capture = false;
};

void announce(DeviceState& d, VkQueue queue, SubmissionPlan& plan) {
  if (!d.pauses) return;
  // A simultaneous-use command buffer listed twice runs its pauses twice: number them so each
  // execution is captured on its own.
  std::map<std::pair<uint64_t, PausePhase>, uint32_t> executions;
  for (PendingPauses& p : plan.pauses) {
    for (PausePoint& pause : p.pauses) pause.occurrence = executions[{pause.pauseId, pause.phase}]++;
    d.pauses->expect(queue, plan.record.index, plan.capture, p.commandBuffer, p.pauses);
  }
}

// Executions of one command buffer on two queues would share its pause events (pause_worker.h,
// shared_pause_tracker.h). Before the driver sees a submission whose pauses may run on several
// queues, wait until no other queue uses those events; the returned lock is held until the
// worker expects this submission's pauses. Where the wait gives up, the submission goes ahead
// and carries a note (CaptureFinding) that its captures may be wrong.
std::unique_lock<std::mutex> admitSharedPauses(DeviceState& d, VkQueue queue, SubmissionPlan& plan) {
  if (!d.pauses) return {};
  std::vector<uint64_t> releases;
  std::vector<uint64_t> commandBuffers;
  for (const PendingPauses& p : plan.pauses)
    for (const PausePoint& pause : p.pauses)
      if (pause.shared) {
        releases.push_back(handleId(pause.release));
        if (commandBuffers.empty() || commandBuffers.back() != p.commandBuffer) commandBuffers.push_back(p.commandBuffer);
      }
  if (releases.empty()) return {};
  // The other queue may wait for something the application does only after this call returns
  // (a host-set event, a timeline value signalled later): then the wait gives up, and says so.
  const std::chrono::milliseconds patience{layerConfig().sharedWaitMilliseconds};
  std::unique_lock lock(d.sharedPausesMutex);
  if (d.pauses->waitUntilFree(queue, releases, patience)) return lock;
  logMessage(LogLevel::Error, "submission %llu: a simultaneous-use command buffer is still running on another queue "
             "after %lld ms; its executions share the layer's pause events, so the captures of this submission may "
             "be wrong", (unsigned long long)plan.record.index, (long long)patience.count());
  for (uint64_t cb : commandBuffers)
    plan.record.notes.push_back({cb, "CLASTRACE-capture-concurrent-execution",
                                 "this command buffer (or a simultaneous-use secondary it executes) was still running "
                                 "its captured commands on another queue when this submission was made, and the layer "
                                 "gave up waiting for it: both executions used the same pause events, so the memory "
                                 "captured for either may have been read at the wrong point"});
  return lock;
}

SubmissionPlan planFor(DeviceState& d, VkQueue queue, VkFence fence, bool synchronization2) {
  SubmissionPlan plan;
  plan.record.index = nextSubmissionIndex();
  plan.record.queue = handleId(queue);
  {
    std::lock_guard lock(d.queuesMutex);
    if (auto f = d.queueFamilies.find(queue); f != d.queueFamilies.end()) plan.record.queueFamily = f->second;
    if (auto i = d.queueIndices.find(queue); i != d.queueIndices.end()) plan.record.queueIndex = i->second;
  }
  plan.record.fence = handleId(fence);
  plan.record.synchronization2 = synchronization2;
  plan.capture = d.sink && layerConfig().submitRange.contains(plan.record.index) &&
                 layerConfig().frameRange.contains(currentFrame());
  return plan;
}

// The executions whose timestamps the trace waits for: read once they are known complete.
void expectTimestamps(DeviceState& d, VkQueue queue, const SubmissionPlan& plan) {
  if (!plan.capture) return;
  std::map<uint64_t, uint32_t> executions;  // read id -> executions in this submission
  std::lock_guard lock(d.timestampsMutex);
  for (const PendingPauses& p : plan.pauses)
    if (p.timestampPool && p.timestamps)
      d.pendingTimestampReads.push_back({queue, plan.record.fence, plan.record.index, p.commandBuffer,
                                         p.timestampPool, p.timestamps, p.timestampReadPauseId,
                                         executions[p.timestampReadPauseId]++});
}

// CLASTRACE_RAY_CHECK: the top levels this submission built (or updated) get their rays traced
// once it completed.
void checkRays(DeviceState& d, VkQueue queue, const SubmissionPlan& plan) {
  if (!plan.capture || layerConfig().rayCheckRays == 0) return;
  std::vector<uint64_t> topLevels;
  for (const PendingPauses& p : plan.pauses)
    for (const PausePoint& pause : p.pauses)
      if (pause.buildNV && pause.buildNV->type == VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV &&
          std::find(topLevels.begin(), topLevels.end(), pause.buildNV->dst) == topLevels.end())
        topLevels.push_back(pause.buildNV->dst);
  runRayChecks(d, queue, plan.record.index, topLevels);
}

VKAPI_ATTR VkResult VKAPI_CALL QueueSubmit(VkQueue queue, uint32_t submitCount, const VkSubmitInfo* pSubmits,
                                           VkFence fence) {
  DeviceState& d = *findDevice(dispatchKey(queue));
  SubmissionPlan plan = planFor(d, queue, fence, false);
  for (uint32_t s = 0; s < submitCount; ++s) {
    const VkSubmitInfo& submit = pSubmits[s];
    const VkTimelineSemaphoreSubmitInfo* timeline = nullptr;
    for (auto* n = (const VkBaseInStructure*)submit.pNext; n; n = n->pNext)
      if (n->sType == VK_STRUCTURE_TYPE_TIMELINE_SEMAPHORE_SUBMIT_INFO)
        timeline = (const VkTimelineSemaphoreSubmitInfo*)n;
    SubmitBatch batch;
    for (uint32_t i = 0; i < submit.waitSemaphoreCount; ++i) {
      uint64_t value = timeline && i < timeline->waitSemaphoreValueCount && timeline->pWaitSemaphoreValues
                           ? timeline->pWaitSemaphoreValues[i]
                           : 0;
      batch.waits.push_back({handleId(submit.pWaitSemaphores[i]), value, submit.pWaitDstStageMask[i]});
    }
    for (uint32_t i = 0; i < submit.signalSemaphoreCount; ++i) {
      uint64_t value = timeline && i < timeline->signalSemaphoreValueCount && timeline->pSignalSemaphoreValues
                           ? timeline->pSignalSemaphoreValues[i]
                           : 0;
      batch.signals.push_back({handleId(submit.pSignalSemaphores[i]), value, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT});
    }
    for (uint32_t i = 0; i < submit.commandBufferCount; ++i) {
      batch.commandBuffers.push_back(handleId(submit.pCommandBuffers[i]));
      plan.pauses.push_back(pausesOf(d, submit.pCommandBuffers[i]));
    }
    plan.record.batches.push_back(std::move(batch));
  }
  auto admitted = admitSharedPauses(d, queue, plan);
  VkResult result = d.next.QueueSubmit(queue, submitCount, pSubmits, fence);
  if (result != VK_SUCCESS) return result;
  announce(d, queue, plan);
  if (admitted.owns_lock()) admitted.unlock();  // the worker tracks this submission's shared pauses now
  expectTimestamps(d, queue, plan);
  if (plan.capture) d.sink->queueSubmitted(plan.record);
  checkRays(d, queue, plan);
  return result;
}

VkResult queueSubmit2(VkQueue queue, uint32_t submitCount, const VkSubmitInfo2* pSubmits, VkFence fence,
                      PFN_vkQueueSubmit2 next) {
  DeviceState& d = *findDevice(dispatchKey(queue));
  SubmissionPlan plan = planFor(d, queue, fence, true);
  for (uint32_t s = 0; s < submitCount; ++s) {
    const VkSubmitInfo2& submit = pSubmits[s];
    SubmitBatch batch;
    for (uint32_t i = 0; i < submit.waitSemaphoreInfoCount; ++i) {
      const auto& w = submit.pWaitSemaphoreInfos[i];
      batch.waits.push_back({handleId(w.semaphore), w.value, w.stageMask});
    }
    for (uint32_t i = 0; i < submit.signalSemaphoreInfoCount; ++i) {
      const auto& g = submit.pSignalSemaphoreInfos[i];
      batch.signals.push_back({handleId(g.semaphore), g.value, g.stageMask});
    }
    for (uint32_t i = 0; i < submit.commandBufferInfoCount; ++i) {
      VkCommandBuffer cb = submit.pCommandBufferInfos[i].commandBuffer;
      batch.commandBuffers.push_back(handleId(cb));
      plan.pauses.push_back(pausesOf(d, cb));
    }
    plan.record.batches.push_back(std::move(batch));
  }
  auto admitted = admitSharedPauses(d, queue, plan);
  VkResult result = next(queue, submitCount, pSubmits, fence);
  if (result != VK_SUCCESS) return result;
  announce(d, queue, plan);
  if (admitted.owns_lock()) admitted.unlock();  // the worker tracks this submission's shared pauses now
  expectTimestamps(d, queue, plan);
  if (plan.capture) d.sink->queueSubmitted(plan.record);
  checkRays(d, queue, plan);
  return result;
}

VKAPI_ATTR VkResult VKAPI_CALL QueueSubmit2(VkQueue queue, uint32_t count, const VkSubmitInfo2* submits, VkFence fence) {
  return queueSubmit2(queue, count, submits, fence, findDevice(dispatchKey(queue))->next.QueueSubmit2);
}
VKAPI_ATTR VkResult VKAPI_CALL QueueSubmit2KHR(VkQueue queue, uint32_t count, const VkSubmitInfo2* submits,
                                               VkFence fence) {
  return queueSubmit2(queue, count, submits, fence, findDevice(dispatchKey(queue))->next.QueueSubmit2KHR);
}

}  // namespace

PFN_vkVoidFunction submitHook(const char* name) {
  static const std::map<std::string, PFN_vkVoidFunction, std::less<>> hooks = {
      {"vkQueueSubmit", (PFN_vkVoidFunction)QueueSubmit},
      {"vkQueueSubmit2", (PFN_vkVoidFunction)QueueSubmit2},
      {"vkQueueSubmit2KHR", (PFN_vkVoidFunction)QueueSubmit2KHR},
  };
  auto it = hooks.find(name);
  return it == hooks.end() ? nullptr : it->second;
}

}  // namespace clastrace::capture
