// SPDX-License-Identifier: Apache-2.0
// Bug: three submissions share a timeline semaphore: a clear of the bottom level's destination
// signals 1, the cluster build signals 2, and the bottom level over the clusters waits for
// value 1 (the author meant 2). Value 1 orders nothing after the cluster build, so the bottom
// level may read CLAS addresses not yet written. --fixed waits for 2.
#include "bug_gpu.h"

using namespace bug_programs;

namespace {

void submit_with_timeline(Gpu& gpu, VkCommandBuffer cb, VkSemaphore timeline, uint64_t wait_value,
                          uint64_t signal_value, VkFence done) {
    vk_ok(vkEndCommandBuffer(cb), "vkEndCommandBuffer");
    VkCommandBufferSubmitInfo command{VK_STRUCTURE_TYPE_COMMAND_BUFFER_SUBMIT_INFO};
    command.commandBuffer = cb;
    VkSemaphoreSubmitInfo wait{VK_STRUCTURE_TYPE_SEMAPHORE_SUBMIT_INFO};
    wait.semaphore = timeline;
    wait.value = wait_value;
    wait.stageMask = VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR;
    VkSemaphoreSubmitInfo signal{VK_STRUCTURE_TYPE_SEMAPHORE_SUBMIT_INFO};
    signal.semaphore = timeline;
    signal.value = signal_value;
    signal.stageMask = VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT;
    VkSubmitInfo2 submit{VK_STRUCTURE_TYPE_SUBMIT_INFO_2};
    submit.commandBufferInfoCount = 1;
    submit.pCommandBufferInfos = &command;
    submit.waitSemaphoreInfoCount = wait_value ? 1 : 0;
    submit.pWaitSemaphoreInfos = &wait;
    submit.signalSemaphoreInfoCount = signal_value ? 1 : 0;
    submit.pSignalSemaphoreInfos = &signal;
    vk_ok(vkQueueSubmit2(gpu.queue, 1, &submit, done), "vkQueueSubmit2");
}

}  // namespace

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "timeline_wrong_value");
    const Quads quads = make_quads(gpu, 3);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);
    BlasBuild blas;
    prepare_blas_build(gpu, clas, quads.count, blas);
    VkSemaphoreTypeCreateInfo timeline_type{VK_STRUCTURE_TYPE_SEMAPHORE_TYPE_CREATE_INFO};
    timeline_type.semaphoreType = VK_SEMAPHORE_TYPE_TIMELINE;
    VkSemaphoreCreateInfo semaphore_info{VK_STRUCTURE_TYPE_SEMAPHORE_CREATE_INFO, &timeline_type};
    VkSemaphore timeline = VK_NULL_HANDLE;
    vk_ok(vkCreateSemaphore(gpu.device, &semaphore_info, nullptr, &timeline), "vkCreateSemaphore");

    VkCommandBuffer clear = gpu.begin();
    vkCmdFillBuffer(clear, blas.objects.buffer, 0, VK_WHOLE_SIZE, 0);
    submit_with_timeline(gpu, clear, timeline, 0, 1, VK_NULL_HANDLE);
    VkCommandBuffer clusters = gpu.begin();
    gpu.cmd_build_clusters(clusters, &clas.info);
    submit_with_timeline(gpu, clusters, timeline, 1, 2, VK_NULL_HANDLE);
    VkCommandBuffer bottom_level = gpu.begin();
    gpu.cmd_build_clusters(bottom_level, &blas.info);
    VkFence done = gpu.fence();
    submit_with_timeline(gpu, bottom_level, timeline, fixed ? 2 : 1, 0, done);
    gpu.wait(done);
    print_range("clas_addresses", clas.addresses.address, clas.addresses.size);
    print_range("clas_objects", clas.objects.address, clas.objects.size);
    vkDestroySemaphore(gpu.device, timeline, nullptr);
    return 0;
}
