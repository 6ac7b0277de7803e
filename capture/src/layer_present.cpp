// vkQueuePresentKHR: the frame boundary. Frames are counted per process (as submissions are):
// frame N is what is submitted after the N-th present call and up to the (N+1)-th, which is
// what CLASTRACE_FRAME_RANGE selects. Every present is recorded, in or out of the range, so a
// trace says where each frame ended and which semaphores the presentation engine consumed.
// vkAcquireNextImage[2]KHR are recorded too (the semaphores and fences they signal), in the
// selected frames only.
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

// A successful acquire is the presentation engine's signal of the semaphore and fence the
// application's next submission (or fence wait) waits on; without the record replay would count
// that wait as unsatisfied. Unlike presents, recorded only in the frames CLASTRACE_FRAME_RANGE
// selects: outside them the submissions that consume the signal are not recorded, and replay
// would take the next frame's acquire for a second signal of a still-signalled semaphore.
void recordAcquire(DeviceState& d, const VkAcquireNextImageInfoKHR& info, uint32_t deviceMask, VkResult result,
                   const uint32_t* pImageIndex) {
  if (!d.capturingNow() || !layerConfig().frameRange.contains(currentFrame())) return;
  AcquireRecord record;
  record.swapchain = handleId(info.swapchain);
  record.timeout = info.timeout;
  record.semaphore = handleId(info.semaphore);
  record.fence = handleId(info.fence);
  record.result = int32_t(result);
  record.deviceMask = deviceMask;
  if ((result == VK_SUCCESS || result == VK_SUBOPTIMAL_KHR) && pImageIndex) record.imageIndex = *pImageIndex;
  d.sink->imageAcquired(record);
}

VKAPI_ATTR VkResult VKAPI_CALL AcquireNextImageKHR(VkDevice device, VkSwapchainKHR swapchain, uint64_t timeout,
                                                   VkSemaphore semaphore, VkFence fence, uint32_t* pImageIndex) {
  DeviceState& d = *findDevice(dispatchKey(device));
  const VkResult result = d.next.AcquireNextImageKHR(device, swapchain, timeout, semaphore, fence, pImageIndex);
  VkAcquireNextImageInfoKHR info{};
  info.sType = VK_STRUCTURE_TYPE_ACQUIRE_NEXT_IMAGE_INFO_KHR;
  info.swapchain = swapchain;
  info.timeout = timeout;
  info.semaphore = semaphore;
  info.fence = fence;
  recordAcquire(d, info, 0, result, pImageIndex);
  return result;
}

VKAPI_ATTR VkResult VKAPI_CALL AcquireNextImage2KHR(VkDevice device, const VkAcquireNextImageInfoKHR* pAcquireInfo,
                                                    uint32_t* pImageIndex) {
  DeviceState& d = *findDevice(dispatchKey(device));
  const VkResult result = d.next.AcquireNextImage2KHR(device, pAcquireInfo, pImageIndex);
  recordAcquire(d, *pAcquireInfo, pAcquireInfo->deviceMask, result, pImageIndex);
  return result;
}

}  // namespace

uint64_t currentFrame() { return presentCalls.load(); }

PFN_vkVoidFunction presentHook(const char* name) {
  if (std::strcmp(name, "vkQueuePresentKHR") == 0) return (PFN_vkVoidFunction)QueuePresentKHR;
  if (std::strcmp(name, "vkAcquireNextImageKHR") == 0) return (PFN_vkVoidFunction)AcquireNextImageKHR;
  if (std::strcmp(name, "vkAcquireNextImage2KHR") == 0) return (PFN_vkVoidFunction)AcquireNextImage2KHR;
  return nullptr;
}

}  // namespace clastrace::capture
