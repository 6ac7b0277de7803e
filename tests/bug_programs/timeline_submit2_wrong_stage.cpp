// SPDX-License-Identifier: Apache-2.0
// The cluster build and the bottom level over its clusters go in two vkQueueSubmit2 calls
// joined by a timeline semaphore (value 1), each VkSemaphoreSubmitInfo with a stageMask of its
// own. One bug per run:
//   (none)          the wait's stageMask is COMPUTE_SHADER (where the author thought cluster
//                   builds run): the bottom level, at ACCELERATION_STRUCTURE_BUILD, is outside
//                   the wait's second scope
//   --signal-copy   the wait is right, but the signal's stageMask is COPY: the cluster build,
//                   at ACCELERATION_STRUCTURE_BUILD, is outside the signal's first scope
//   --fixed         both stageMasks ACCELERATION_STRUCTURE_BUILD
#include "bug_gpu.h"

using namespace bug_programs;

namespace {

VkSemaphore make_timeline(Gpu& gpu) {
    VkSemaphoreTypeCreateInfo type{VK_STRUCTURE_TYPE_SEMAPHORE_TYPE_CREATE_INFO};
    type.semaphoreType = VK_SEMAPHORE_TYPE_TIMELINE;
    VkSemaphoreCreateInfo info{VK_STRUCTURE_TYPE_SEMAPHORE_CREATE_INFO, &type};
    VkSemaphore timeline = VK_NULL_HANDLE;
    vk_ok(vkCreateSemaphore(gpu.device, &info, nullptr, &timeline), "vkCreateSemaphore");
    return timeline;
}

// Submits `cb`, waiting on (`wait_stage`, value 1) when `wait_stage` is set and signalling
// (`signal_stage`, value 1) when `signal_stage` is set.
void submit(Gpu& gpu, VkCommandBuffer cb, VkSemaphore timeline, VkPipelineStageFlags2 wait_stage,
            VkPipelineStageFlags2 signal_stage, VkFence done) {
    vk_ok(vkEndCommandBuffer(cb), "vkEndCommandBuffer");
    VkCommandBufferSubmitInfo command{VK_STRUCTURE_TYPE_COMMAND_BUFFER_SUBMIT_INFO};
    command.commandBuffer = cb;
    VkSemaphoreSubmitInfo wait{VK_STRUCTURE_TYPE_SEMAPHORE_SUBMIT_INFO, nullptr, timeline, 1,
                               wait_stage};
    VkSemaphoreSubmitInfo signal{VK_STRUCTURE_TYPE_SEMAPHORE_SUBMIT_INFO, nullptr, timeline, 1,
                                 signal_stage};
    VkSubmitInfo2 info{VK_STRUCTURE_TYPE_SUBMIT_INFO_2};
    info.commandBufferInfoCount = 1;
    info.pCommandBufferInfos = &command;
    info.waitSemaphoreInfoCount = wait_stage ? 1 : 0;
    info.pWaitSemaphoreInfos = &wait;
    info.signalSemaphoreInfoCount = signal_stage ? 1 : 0;
    info.pSignalSemaphoreInfos = &signal;
    vk_ok(vkQueueSubmit2(gpu.queue, 1, &info, done), "vkQueueSubmit2");
}

}  // namespace

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    const bool signal_copy = has_flag(argc, argv, "--signal-copy");
    Gpu gpu;
    open(gpu, "timeline_submit2_wrong_stage");
    const Quads quads = make_quads(gpu, 3);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);
    BlasBuild blas;
    prepare_blas_build(gpu, clas, quads.count, blas);
    VkSemaphore timeline = make_timeline(gpu);
    constexpr VkPipelineStageFlags2 build =
        VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR;

    VkCommandBuffer clusters = gpu.begin();
    gpu.cmd_build_clusters(clusters, &clas.info);
    submit(gpu, clusters, timeline, 0, signal_copy ? VK_PIPELINE_STAGE_2_COPY_BIT : build,
           VK_NULL_HANDLE);
    VkCommandBuffer bottom_level = gpu.begin();
    gpu.cmd_build_clusters(bottom_level, &blas.info);
    VkFence done = gpu.fence();
    const bool wait_right = fixed || signal_copy;
    submit(gpu, bottom_level, timeline, wait_right ? build : VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT,
           0, done);
    gpu.wait(done);
    print_range("clas_addresses", clas.addresses.address, clas.addresses.size);
    print_range("clas_objects", clas.objects.address, clas.objects.size);
    vkDestroySemaphore(gpu.device, timeline, nullptr);
    return 0;
}
