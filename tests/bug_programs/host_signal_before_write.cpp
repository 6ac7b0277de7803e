// SPDX-License-Identifier: Apache-2.0
// Bug: the engine submits the cluster build early, waiting on a timeline semaphore (value 1 at
// ACCELERATION_STRUCTURE_BUILD) that the host signals with vkSignalSemaphore once this frame's
// src infos are in mapped memory. It signals first and writes the infos after, so the build
// may read them while the host writes. --fixed writes, then signals.
#include "bug_gpu.h"

#include <vector>

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "host_signal_before_write");
    const Quads quads = make_quads(gpu, 3);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);
    const std::vector<unsigned char> frame(clas.infos.host, clas.infos.host + clas.infos.size);
    std::memset(clas.infos.host, 0, clas.infos.size);
    VkSemaphoreTypeCreateInfo type{VK_STRUCTURE_TYPE_SEMAPHORE_TYPE_CREATE_INFO};
    type.semaphoreType = VK_SEMAPHORE_TYPE_TIMELINE;
    VkSemaphoreCreateInfo semaphore_info{VK_STRUCTURE_TYPE_SEMAPHORE_CREATE_INFO, &type};
    VkSemaphore ready = VK_NULL_HANDLE;
    vk_ok(vkCreateSemaphore(gpu.device, &semaphore_info, nullptr, &ready), "vkCreateSemaphore");

    VkCommandBuffer cb = gpu.begin();
    gpu.cmd_build_clusters(cb, &clas.info);
    vk_ok(vkEndCommandBuffer(cb), "vkEndCommandBuffer");
    VkCommandBufferSubmitInfo command{VK_STRUCTURE_TYPE_COMMAND_BUFFER_SUBMIT_INFO};
    command.commandBuffer = cb;
    VkSemaphoreSubmitInfo wait{VK_STRUCTURE_TYPE_SEMAPHORE_SUBMIT_INFO, nullptr, ready, 1,
                               VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR};
    VkSubmitInfo2 submit{VK_STRUCTURE_TYPE_SUBMIT_INFO_2};
    submit.waitSemaphoreInfoCount = 1;
    submit.pWaitSemaphoreInfos = &wait;
    submit.commandBufferInfoCount = 1;
    submit.pCommandBufferInfos = &command;
    VkFence done = gpu.fence();
    vk_ok(vkQueueSubmit2(gpu.queue, 1, &submit, done), "vkQueueSubmit2");

    const VkSemaphoreSignalInfo signal{VK_STRUCTURE_TYPE_SEMAPHORE_SIGNAL_INFO, nullptr, ready, 1};
    if (fixed) std::memcpy(clas.infos.host, frame.data(), frame.size());
    vk_ok(vkSignalSemaphore(gpu.device, &signal), "vkSignalSemaphore");
    if (!fixed) std::memcpy(clas.infos.host, frame.data(), frame.size());
    gpu.wait(done);
    print_range("infos", clas.infos.address, clas.infos.size);
    vkDestroySemaphore(gpu.device, ready, nullptr);
    return 0;
}
