// vkQueuePresentKHR: the frame boundary. Frames are counted per process (as submissions are):
// frame N is what is submitted after the N-th present call and up to the (N+1)-th, which is
// what CLASTRACE_FRAME_RANGE selects. Every present is recorded, in or out of the range, so a
// trace says where each frame ended and which semaphores the presentation engine consumed.
#include "layer_state.h"

#include <atomic>
#include <cstring>

namespace clastrace::capture {
namespace {

std::atomic<uint64_t> presentCalls{0};

VKAPI_ATTR VkResult VKAPI_CALL QueuePresentKHR(VkQueue queue, const VkPresentInfoKHR* pPresentInfo) {
  DeviceState& d = *findDevice(dispatchKey(queue));
  const VkResult result = d.next.QueuePresentKHR(queue, pPresentInfo);
  // A rejected present (VK_ERROR_OUT_OF_DATE_KHR, ...) still waits on its semaphores, and the
  // application has finished its frame either way: every call ends one.
  const uint64_t frame = presentCalls.fetch_add(1);
  if (d.capturingNow()) {
    PresentRecord record;
    record.queue = handleId(queue);
    record.frame = frame;
    record.result = int32_t(result);
    for (uint32_t i = 0; i < pPresentInfo->waitSemaphoreCount; ++i)
      record.waitSemaphores.push_back(handleId(pPresentInfo->pWaitSemaphores[i]));
    for (uint32_t i = 0; i < pPresentInfo->swapchainCount; ++i) {
      record.swapchains.push_back(handleId(pPresentInfo->pSwapchains[i]));
      record.imageIndices.push_back(pPresentInfo->pImageIndices[i]);
    }
    d.sink->queuePresented(record);
  }
  return result;
}

}  // namespace

uint64_t currentFrame() { return presentCalls.load(); }

PFN_vkVoidFunction presentHook(const char* name) {
  return std::strcmp(name, "vkQueuePresentKHR") == 0 ? (PFN_vkVoidFunction)QueuePresentKHR : nullptr;
}

}  // namespace clastrace::capture
