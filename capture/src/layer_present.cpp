// SPDX-License-Identifier: Apache-2.0
// vkQueuePresentKHR: the frame boundary. Frames are counted per process (as submissions are):
// frame N is what is submitted after the N-th present call and up to the (N+1)-th, which is
// what CLASTRACE_FRAME_RANGE selects (headless programs: VkFrameBoundaryEXT,
// layer_frame_boundary.cpp). Every present is recorded, in or out of the range, so a
// trace says where each frame ended and which semaphores the presentation engine consumed.
// vkAcquireNextImage[2]KHR are recorded too (the semaphores and fences they signal), in the
// selected frames only.
#include "layer_state.h"

#include <cstring>

namespace clastrace::capture {
namespace {

VKAPI_ATTR VkResult VKAPI_CALL QueuePresentKHR(VkQueue queue,
                                               const VkPresentInfoKHR* p_present_info) {
    DeviceState& d = *find_device(dispatch_key(queue));
    const VkFrameBoundaryEXT* boundary = find_frame_boundary(p_present_info->pNext);
    VkResult result;
    {
        ChainUnlink hide_boundary(d.frame_boundary_served ? p_present_info : nullptr,
                                  VK_STRUCTURE_TYPE_FRAME_BOUNDARY_EXT);
        result = d.next.QueuePresentKHR(queue, p_present_info);
    }
    // A rejected present (VK_ERROR_OUT_OF_DATE_KHR, ...) still waits on its semaphores, and the
    // application has finished its frame either way: every call ends one.
    const uint64_t frame = count_present();
    if (boundary)
        frame_boundary_marked(d, queue, *boundary, FrameBoundaryCarrier::kPresent, 0, 0, frame);
    if (d.capturing_now()) {
        PresentRecord record;
        record.queue = handle_id(queue);
        record.frame = frame;
        record.result = int32_t(result);
        for (uint32_t i = 0; i < p_present_info->waitSemaphoreCount; ++i)
            record.wait_semaphores.push_back(handle_id(p_present_info->pWaitSemaphores[i]));
        for (uint32_t i = 0; i < p_present_info->swapchainCount; ++i) {
            record.swapchains.push_back(handle_id(p_present_info->pSwapchains[i]));
            record.image_indices.push_back(p_present_info->pImageIndices[i]);
        }
        d.sink->queue_presented(record);
    }
    return result;
}

// A successful acquire is the presentation engine's signal of the semaphore and fence the
// application's next submission (or fence wait) waits on; without the record replay would count
// that wait as unsatisfied. Unlike presents, recorded only in the frames CLASTRACE_FRAME_RANGE
// selects: outside them the submissions that consume the signal are not recorded, and replay
// would take the next frame's acquire for a second signal of a still-signalled semaphore.
void record_acquire(DeviceState& d, const VkAcquireNextImageInfoKHR& info, uint32_t device_mask,
                    VkResult result, const uint32_t* p_image_index) {
    if (!d.capturing_now() || !layer_config().frame_range.contains(current_frame())) return;
    AcquireRecord record;
    record.swapchain = handle_id(info.swapchain);
    record.timeout = info.timeout;
    record.semaphore = handle_id(info.semaphore);
    record.fence = handle_id(info.fence);
    record.result = int32_t(result);
    record.device_mask = device_mask;
    if ((result == VK_SUCCESS || result == VK_SUBOPTIMAL_KHR) && p_image_index)
        record.image_index = *p_image_index;
    d.sink->image_acquired(record);
}

VKAPI_ATTR VkResult VKAPI_CALL AcquireNextImageKHR(VkDevice device, VkSwapchainKHR swapchain,
                                                   uint64_t timeout, VkSemaphore semaphore,
                                                   VkFence fence, uint32_t* p_image_index) {
    DeviceState& d = *find_device(dispatch_key(device));
    const VkResult result =
        d.next.AcquireNextImageKHR(device, swapchain, timeout, semaphore, fence, p_image_index);
    VkAcquireNextImageInfoKHR info{};
    info.sType = VK_STRUCTURE_TYPE_ACQUIRE_NEXT_IMAGE_INFO_KHR;
    info.swapchain = swapchain;
    info.timeout = timeout;
    info.semaphore = semaphore;
    info.fence = fence;
    record_acquire(d, info, 0, result, p_image_index);
    return result;
}

VKAPI_ATTR VkResult VKAPI_CALL AcquireNextImage2KHR(VkDevice device,
                                                    const VkAcquireNextImageInfoKHR* p_acquire_info,
                                                    uint32_t* p_image_index) {
    DeviceState& d = *find_device(dispatch_key(device));
    const VkResult result = d.next.AcquireNextImage2KHR(device, p_acquire_info, p_image_index);
    record_acquire(d, *p_acquire_info, p_acquire_info->deviceMask, result, p_image_index);
    return result;
}

}  // namespace

PFN_vkVoidFunction present_hook(const char* name) {
    if (std::strcmp(name, "vkQueuePresentKHR") == 0) return (PFN_vkVoidFunction)QueuePresentKHR;
    if (std::strcmp(name, "vkAcquireNextImageKHR") == 0)
        return (PFN_vkVoidFunction)AcquireNextImageKHR;
    if (std::strcmp(name, "vkAcquireNextImage2KHR") == 0)
        return (PFN_vkVoidFunction)AcquireNextImage2KHR;
    return nullptr;
}

}  // namespace clastrace::capture
